"""Articulated bundle adjustment: the joints refined against the images of both configurations.

The joints of :func:`artrecon.articulation.articulate` come from the links' A -> B motions, each
fitted to its 3D-3D matches (triangulated points). The images hold that evidence more directly:
each matched point was seen, as a 2D feature, in several images of A and several of B. This
module solves one robust least-squares problem over both configurations:

- unknowns: each matched point ``X_i`` (A's frame), a small offset ``d_i`` per match (the A and
  B features of one match are not quite the same physical point: prior ``d_i ~ N(0, s_d^2 I)``),
  the base's A -> B motion (rigid with given camera poses; a similarity otherwise, the two SfM
  frames' scale) and each joint: revolute (axis direction, a point on it, angle), prismatic
  (direction, displacement); a coupled joint's value is a fixed multiple of its leader's;
- link ``k``'s motion follows from the kinematic tree: ``M_k = M_parent o J_k(axis, value)``;
- residuals: the reprojection errors of ``X_i`` in A's images where its A feature was seen, of
  ``M_link(X_i) + d_i`` in B's images where its B feature was seen (pixels, over the image
  noise ``s_px``), and ``d_i / s_d``; Cauchy-robust;
- the cameras held at the given poses (the arm's forward kinematics; or SfM's own, refined by
  its bundle adjustment).

The noise levels ``s_px`` and ``s_d`` are estimated with the solution (expectation-maximisation:
a few rounds of solving, then re-estimating them from the residuals and the points' posterior
spread). The joints' covariance is the inverse of the Gauss-Newton information with the points
and offsets marginalised (Schur complement), scaled by the reduced chi-square when above 1.

Solver: scipy's ``least_squares`` (trust region reflective) with a sparse Jacobian by finite
differences (columns grouped by the sparsity: each point touches only its own observations).

Acceptance (the refinement replaces nothing it does not beat): a joint keeps its refined figures
only when the solver converged, the refined motion keeps the joint's type and direction of
motion, the robust cost fell, and the refined axis lies within the initial estimate's own
uncertainty (its bootstrap spread, :mod:`artrecon.confidence`), widened by the refined one:
``angle(refined, initial) <= k * hypot(spread_initial, sigma_refined)`` (``k`` =
:attr:`RefineConfig.max_change_sigma`). A refinement that jumps beyond what either estimate
allows is a sign of a wrong local minimum or bad tracks: the initial joint stays, and the record
says why.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from artrecon.geometry import exp_so3, skew
from artrecon.model import Joint
from artrecon.procrustes import Similarity

log = logging.getLogger(__name__)

__all__ = ["RefineConfig", "Views", "Tracks", "Refinement", "refine_joints", "tracks_of",
           "views_of"]

#: Observations per configuration a match needs to enter the problem.
MIN_OBSERVATIONS = 2


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the articulated bundle adjustment (:func:`refine_joints`)."""

    enabled: bool = True
    """Refine the joints against the images (off: the joints from the matches' motions)."""
    loss_scale: float = 3.0
    """Cauchy scale of the residuals, in standard deviations."""
    rounds: int = 3
    """Expectation-maximisation rounds (solve, then re-estimate the noise levels)."""
    max_evaluations: int = 100
    """Residual evaluations per solve at most (beside the Jacobian's)."""
    max_change_sigma: float = 3.0
    """A refined axis may move from the initial one by at most this many combined standard
    deviations (the initial's bootstrap spread and the refined one's, in quadrature)."""


@dataclass(frozen=True)
class Views:
    """The cameras of one configuration, held fixed: ``x_cam = rotations[v] @ x + translations[v]``
    and the mean focal length (pixels), which turns normalised image coordinates into pixels."""

    rotations: np.ndarray
    translations: np.ndarray
    focal: np.ndarray


@dataclass(frozen=True)
class Tracks:
    """2D observations of the matches' points in one configuration's images: observation ``o`` is
    match ``point[o]`` seen in view ``view[o]`` at normalised image coordinates ``uv[o]``
    (undistorted, ``x / z, y / z`` in the camera frame)."""

    point: np.ndarray
    view: np.ndarray
    uv: np.ndarray

    def __len__(self) -> int:
        return len(self.point)


@dataclass
class Refinement:
    """What :func:`refine_joints` found."""

    joints: list[Joint]
    """The joints, refined where accepted (else the initial ones), in the input's order."""
    transforms: list[Similarity]
    """Each link's A -> B motion from the joints returned."""
    accepted: list[bool]
    """Per joint: whether its refined figures were kept."""
    records: list[dict]
    """Per joint: its uncertainty (1 sigma: ``axis_deg`` the RMS angle of the axis direction,
    ``position`` the RMS offset of the axis line in the plane normal to it (revolute; model
    units), ``state`` in rad or model units), the refined and initial figures and the verdict."""
    summary: dict = field(default_factory=dict)
    """Points, observations, noise levels, costs, iterations, seconds."""


def views_of(reconstruction) -> tuple[Views, dict[int, int]]:
    """The registered images of a pycolmap Reconstruction as :class:`Views`, and the row of each
    image id."""
    ids = sorted(reconstruction.reg_image_ids()) if hasattr(reconstruction, "reg_image_ids") \
        else sorted(reconstruction.images)
    rots = np.zeros((len(ids), 3, 3))
    trans = np.zeros((len(ids), 3))
    focal = np.zeros(len(ids))
    for k, iid in enumerate(ids):
        image = reconstruction.images[iid]
        camera = reconstruction.cameras[image.camera_id]
        m = image.cam_from_world().matrix()
        rots[k], trans[k] = m[:, :3], m[:, 3]
        focal[k] = 0.5 * (camera.focal_length_x + camera.focal_length_y)
    return Views(rots, trans, focal), {iid: k for k, iid in enumerate(ids)}


def tracks_of(reconstruction, point_ids, rows: dict[int, int]) -> Tracks:
    """The 2D observations (:class:`Tracks`) of the given SfM points (``point_ids[i]`` is match
    ``i``; -1 or an id the reconstruction lacks: no observation), lens distortion removed."""
    point, view, xy, cams = [], [], [], []
    for i, pid in enumerate(np.asarray(point_ids, np.int64).reshape(-1)):
        if pid < 0 or not reconstruction.exists_point3D(int(pid)):
            continue
        for el in reconstruction.points3D[int(pid)].track.elements:
            if el.image_id not in rows:
                continue
            image = reconstruction.images[el.image_id]
            point.append(i)
            view.append(rows[el.image_id])
            xy.append(image.points2D[el.point2D_idx].xy)
            cams.append(image.camera_id)
    uv = np.zeros((len(point), 2))
    cams = np.asarray(cams, np.int64)
    xy = np.asarray(xy, float).reshape(-1, 2)
    for cid in np.unique(cams):
        sel = cams == cid
        uv[sel] = reconstruction.cameras[int(cid)].cam_from_img(xy[sel])
    return Tracks(np.asarray(point, np.int64), np.asarray(view, np.int64), uv)


# --------------------------------------------------------------------------- the kinematic model

@dataclass
class _JointBlock:
    index: int
    type: str
    parent: int
    child: int
    u0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    q0: np.ndarray
    value0: float
    offset: int            # first global parameter of this joint
    leader: int | None     # coupled: the joint whose value this one follows
    ratio: float


class _Kinematics:
    """Parameter layout of the base motion and the joints, and the links' motions from them."""

    def __init__(self, joints: list[Joint], n_links: int, root: int, base: Similarity,
                 scale_free: bool, couplings: dict[int, tuple[int, float]]):
        self.n_links, self.root, self.base = n_links, root, base
        self.scale_free = scale_free
        self.blocks: list[_JointBlock] = []
        offset = 7 if scale_free else 6
        order = _tree_order(joints, root)
        for j in order:
            jt = joints[j]
            u0 = np.asarray(jt.axis_direction, float)
            e1, e2 = _tangent_basis(u0)
            leader, ratio = couplings.get(j, (None, 1.0))
            block = _JointBlock(j, jt.type, jt.parent, jt.child, u0, e1, e2,
                                np.asarray(jt.axis_point, float), float(jt.motion), offset,
                                leader, float(ratio))
            # revolute: 2 axis, 2 point, 1 angle; prismatic: 2 direction, 1 displacement
            offset += (4 if jt.type == "revolute" else 2) + (0 if leader is not None else 1)
            self.blocks.append(block)
        self.n_params = offset
        self._by_index = {b.index: b for b in self.blocks}

    def value(self, g: np.ndarray, block: _JointBlock) -> float:
        if block.leader is not None:
            return block.ratio * self.value(g, self._by_index[block.leader])
        k = block.offset + (4 if block.type == "revolute" else 2)
        return block.value0 + g[k]

    def joint(self, g: np.ndarray, block: _JointBlock):
        """Axis direction, axis point and value of a joint at parameters ``g``."""
        o = block.offset
        u = block.u0 + g[o] * block.e1 + g[o + 1] * block.e2
        u = u / np.linalg.norm(u)
        if block.type == "revolute":
            q = block.q0 + g[o + 2] * block.e1 + g[o + 3] * block.e2
        else:
            q = block.q0
        return u, q, self.value(g, block)

    def motions(self, g: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(scale, rotations (L, 3, 3), translations (L, 3)): each link's A -> B motion."""
        scale = self.base.scale * (np.exp(g[6]) if self.scale_free else 1.0)
        rots = np.zeros((self.n_links, 3, 3))
        trans = np.zeros((self.n_links, 3))
        rots[self.root] = exp_so3(g[:3]) @ self.base.rotation
        trans[self.root] = self.base.translation + g[3:6]
        for b in self.blocks:
            u, q, v = self.joint(g, b)
            if b.type == "revolute":
                K = skew(u)
                rj = np.eye(3) + np.sin(v) * K + (1 - np.cos(v)) * K @ K
                tj = q - rj @ q
            else:
                rj, tj = np.eye(3), v * u
            rots[b.child] = rots[b.parent] @ rj
            trans[b.child] = scale * rots[b.parent] @ tj + trans[b.parent]
        return scale, rots, trans

    def joints_at(self, g: np.ndarray, initial: list[Joint], scale: float,
                  rots: np.ndarray, trans: np.ndarray) -> list[Joint]:
        out = list(initial)
        for b in self.blocks:
            u, q, v = self.joint(g, b)
            rel = (Similarity(rots[b.parent], trans[b.parent], scale).inverse()
                   @ Similarity(rots[b.child], trans[b.child], scale))
            jt = initial[b.index]
            out[b.index] = replace(jt, axis_direction=u, axis_point=q,
                                   state_b=jt.state_a + v, relative_transform=rel,
                                   confidence=dict(jt.confidence))
        return out


def _tree_order(joints: list[Joint], root: int) -> list[int]:
    """Joint indices parents first (breadth-first from the root)."""
    order, reached = [], {root}
    pending = list(range(len(joints)))
    while pending:
        ready = [j for j in pending if joints[j].parent in reached]
        if not ready:
            raise ValueError("the joints do not form a tree from the root link "
                             f"{root}: {[(joints[j].parent, joints[j].child) for j in pending]}")
        for j in ready:
            order.append(j)
            reached.add(joints[j].child)
            pending.remove(j)
    return order


def _tangent_basis(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[np.argmin(np.abs(u))]
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(u, e1)


# --------------------------------------------------------------------------- the problem

class _Problem:
    def __init__(self, kin: _Kinematics, points: np.ndarray, labels: np.ndarray,
                 tracks_a: Tracks, tracks_b: Tracks, views_a: Views, views_b: Views):
        self.kin, self.labels = kin, labels
        self.n = len(points)
        self.points0 = points
        self.ta, self.tb, self.va, self.vb = tracks_a, tracks_b, views_a, views_b
        self.fa = views_a.focal[tracks_a.view]
        self.fb = views_b.focal[tracks_b.view]
        self.sigma_px = 0.5
        self.sigma_d = 1e-4
        self.g_fixed: np.ndarray | None = None  # joints held (the initial's cost)

    # layout: [globals (g) | X (3n) | d (3n)]
    def split(self, x: np.ndarray):
        g = self.kin.n_params
        return x[:g], x[g:g + 3 * self.n].reshape(-1, 3), x[g + 3 * self.n:].reshape(-1, 3)

    def x0(self) -> np.ndarray:
        return np.r_[np.zeros(self.kin.n_params), self.points0.ravel(), np.zeros(3 * self.n)]

    def reprojection(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel residuals (k, 2) of A's and B's observations."""
        g, X, d = self.split(x)
        scale, rots, trans = self.kin.motions(g)
        ra = _project(self.va, self.ta, X) - self.ta.uv
        lab = self.labels
        Y = scale * np.einsum("nij,nj->ni", rots[lab], X) + trans[lab] + d
        rb = _project(self.vb, self.tb, Y) - self.tb.uv
        return ra * self.fa[:, None], rb * self.fb[:, None]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        if self.g_fixed is not None:
            x = np.r_[self.g_fixed, x]
        ra, rb = self.reprojection(x)
        _, _, d = self.split(x)
        return np.r_[ra.ravel() / self.sigma_px, rb.ravel() / self.sigma_px,
                     d.ravel() / self.sigma_d]

    def sparsity(self, with_globals: bool = True) -> sparse.csr_matrix:
        g = self.kin.n_params if with_globals else 0
        n = self.n
        rows, cols = [], []
        r0 = 0
        for tr, has_d in ((self.ta, False), (self.tb, True)):
            k = len(tr)
            obs_rows = r0 + 2 * np.arange(k)
            for c in range(2):
                r = obs_rows + c
                for a in range(3):
                    rows.append(r)
                    cols.append(g + 3 * tr.point + a)
                    if has_d:
                        rows.append(r)
                        cols.append(g + 3 * n + 3 * tr.point + a)
                if has_d and g:
                    rows.append(np.repeat(r, g))
                    cols.append(np.tile(np.arange(g), k))
            r0 += 2 * k
        rows.append(r0 + np.arange(3 * n))
        cols.append(g + 3 * n + np.arange(3 * n))
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        return sparse.csr_matrix((np.ones(len(rows), np.int8), (rows, cols)),
                                 shape=(r0 + 3 * n, g + 6 * n))


def _project(views: Views, tracks: Tracks, X: np.ndarray) -> np.ndarray:
    xc = np.einsum("oij,oj->oi", views.rotations[tracks.view], X[tracks.point]) \
        + views.translations[tracks.view]
    z = xc[:, 2:3]
    z = np.where(np.abs(z) < 1e-9, 1e-9, z)
    return xc[:, :2] / z


def _solve(problem: _Problem, x0: np.ndarray, config: RefineConfig, with_globals: bool):
    if with_globals:
        problem.g_fixed = None
        start = x0
    else:
        problem.g_fixed = x0[:problem.kin.n_params]
        start = x0[problem.kin.n_params:]
    res = least_squares(problem.residuals, start, jac_sparsity=problem.sparsity(with_globals),
                        loss="cauchy", f_scale=config.loss_scale, method="trf",
                        x_scale="jac", max_nfev=config.max_evaluations, tr_solver="lsmr")
    x = res.x if with_globals else np.r_[problem.g_fixed, res.x]
    problem.g_fixed = None
    return x, res


def _marginal_covariance(jac, n_globals: int, n_points: int) -> np.ndarray:
    """Covariance (per unit residual variance) of the global parameters with the points and
    offsets marginalised: the inverse of the Schur complement of the information J^T J."""
    J = sparse.csc_matrix(jac)
    g = n_globals
    Jg = J[:, :g].toarray()
    H_gg = Jg.T @ Jg
    Jp = J[:, g:]
    H_pg = (Jp.T @ sparse.csr_matrix(Jg)).toarray()  # (6n, g)
    H_pp = (Jp.T @ Jp).tocsr()
    # per match: the 6 columns X_i (3) and d_i (3)
    idx = np.stack([np.r_[3 * i:3 * i + 3, 3 * n_points + 3 * i:3 * n_points + 3 * i + 3]
                    for i in range(n_points)]) if n_points else np.zeros((0, 6), int)
    blocks = np.zeros((n_points, 6, 6))
    for a in range(6):
        for b in range(6):
            blocks[:, a, b] = np.asarray(H_pp[idx[:, a], idx[:, b]]).ravel()
    blocks += np.eye(6) * 1e-12 * np.maximum(1.0, np.abs(blocks).max())
    inv = np.linalg.inv(blocks)
    Bg = H_pg[idx]  # (n, 6, g)
    S = H_gg - np.einsum("nai,nab,nbj->ij", Bg, inv, Bg)
    return np.linalg.pinv(S), inv


def refine_joints(points_a: np.ndarray, labels: np.ndarray, tracks_a: Tracks, tracks_b: Tracks,
                  views_a: Views, views_b: Views, joints: list[Joint], root: int,
                  base: Similarity, n_links: int, *, scale_known: bool,
                  couplings: dict[int, tuple[int, float]] | None = None,
                  config: RefineConfig = RefineConfig()) -> Refinement:  # noqa: B008
    """The joints refined by articulated bundle adjustment (see the module's docstring).

    Parameters
    ----------
    points_a : (n, 3)
        The matches' points in A's frame (their starting positions).
    labels : (n,) int
        Link of each match (-1: an outlier, left out).
    tracks_a, tracks_b : Tracks
        Each match's 2D observations in A's and B's images (``point`` indexes ``points_a``).
    views_a, views_b : Views
        The two configurations' cameras (held fixed).
    joints : list of Joint
        The initial joints (a tree from ``root``; ``parent``/``child`` index the links).
    root : int
        The base link, whose A -> B motion is ``base`` to begin with.
    base : Similarity
    n_links : int
    scale_known : bool
        Both configurations' frames metric (given camera poses): the motions are rigid. Else
        the base's motion is a similarity (the common scale refined too).
    couplings : dict, optional
        ``{joint index: (leader joint index, ratio)}``: the joint's value is ``ratio`` times the
        leader's (one parameter for both).
    config : RefineConfig

    Returns
    -------
    Refinement
    """
    t0 = time.perf_counter()
    couplings = dict(couplings or {})
    labels = np.asarray(labels, np.int64)
    points_a = np.asarray(points_a, float)
    # matches on a link, seen often enough in both configurations
    na = np.bincount(tracks_a.point, minlength=len(points_a))
    nb = np.bincount(tracks_b.point, minlength=len(points_a))
    use = (labels >= 0) & (na >= MIN_OBSERVATIONS) & (nb >= MIN_OBSERVATIONS)
    renum = np.full(len(points_a), -1)
    renum[use] = np.arange(int(use.sum()))

    def keep(tr: Tracks) -> Tracks:
        sel = use[tr.point]
        return Tracks(renum[tr.point[sel]], tr.view[sel], tr.uv[sel])

    tracks_a, tracks_b = keep(tracks_a), keep(tracks_b)
    kin = _Kinematics(joints, n_links, root, base, not scale_known, couplings)
    problem = _Problem(kin, points_a[use], labels[use], tracks_a, tracks_b, views_a, views_b)
    n = problem.n
    # the noise levels to begin with: the reprojection errors of the initial model, and the
    # matches' disagreement with their link's initial motion
    x = problem.x0()
    ra, rb = problem.reprojection(x)
    problem.sigma_px = max(1.4826 * float(np.median(np.abs(np.r_[ra.ravel(), rb.ravel()]))), 0.05)
    problem.sigma_d = max(_extent(points_a[use]) * 1e-4, 1e-12)
    nfev, status = 0, 0
    cov_g = None
    for _ in range(max(1, config.rounds)):
        x, res = _solve(problem, x, config, with_globals=True)
        nfev += res.nfev
        status = res.status
        cov_g, cov_p = _marginal_covariance(res.jac, kin.n_params, n)
        # EM: the image noise from the reprojection residuals (robust), the offsets' spread from
        # their estimates and their posterior variance
        ra, rb = problem.reprojection(x)
        r = np.r_[ra.ravel(), rb.ravel()]
        problem.sigma_px = max(1.4826 * float(np.median(np.abs(r))), 0.02)
        _, _, d = problem.split(x)
        post = np.einsum("nii->n", cov_p[:, 3:, 3:]) * problem.sigma_d ** 2
        problem.sigma_d = max(float(np.sqrt(np.median(np.sum(d * d, axis=1) + post) / 3)),
                              _extent(points_a[use]) * 1e-7)
    # final covariance at the final noise levels, scaled by the reduced chi-square when above 1
    x, res = _solve(problem, x, config, with_globals=True)
    nfev += res.nfev
    status = res.status
    cov_g, _ = _marginal_covariance(res.jac, kin.n_params, n)
    dof = max(len(res.fun) - len(x), 1)
    chi2 = float(2 * res.cost / dof)
    cov_g = cov_g * max(1.0, chi2)
    cost_refined = float(res.cost)
    # the initial joints' cost at the same noise levels (points and offsets re-fitted)
    x_init = problem.x0()
    x_init[kin.n_params:] = x[kin.n_params:]
    x_held, res_held = _solve(problem, x_init, config, with_globals=False)
    cost_initial = float(res_held.cost)

    g = x[:kin.n_params]
    scale, rots, trans = kin.motions(g)
    refined = kin.joints_at(g, joints, scale, rots, trans)
    converged = bool(status > 0 and np.all(np.isfinite(x)))
    out_joints, accepted, records = list(joints), [False] * len(joints), [None] * len(joints)
    for b in kin.blocks:
        rec = _uncertainty(b, cov_g, kin.n_params)
        new, old = refined[b.index], joints[b.index]
        change = float(np.degrees(np.arccos(np.clip(new.axis_direction @ old.axis_direction,
                                                    -1, 1))))
        spread = (old.confidence.get("bootstrap", {}) or {}).get("axis_spread_deg")
        allowed = (config.max_change_sigma * float(np.hypot(spread, rec["axis_deg"]))
                   if spread is not None else np.inf)
        same_sign = np.sign(new.motion) == np.sign(old.motion) or old.motion == 0
        if not converged:
            verdict = f"not converged (solver status {status})"
        elif not cost_refined < cost_initial:
            verdict = "the cost did not fall"
        elif not same_sign:
            verdict = "the refined motion reverses the joint's direction"
        elif not change <= allowed:
            verdict = (f"the axis moved {change:.3f} deg, beyond {allowed:.3f} deg "
                       f"({config.max_change_sigma:g} sigma of the initial's bootstrap spread "
                       "and the refined uncertainty)")
        else:
            verdict = "accepted"
        ok = verdict == "accepted"
        accepted[b.index] = ok
        rec.update({"verdict": verdict, "axis_change_deg": change,
                    "refined": _figures(new), "initial": _figures(old)})
        records[b.index] = rec
        joint = new if ok else old
        joint.confidence["refinement"] = rec
        out_joints[b.index] = joint
    # the links' motions from the joints kept
    transforms = _link_transforms(kin, out_joints, accepted, g, base, scale)
    summary = {"points": n, "observations_a": len(tracks_a), "observations_b": len(tracks_b),
               "sigma_px": problem.sigma_px, "sigma_offset": problem.sigma_d,
               "chi2_reduced": chi2, "cost_initial": cost_initial, "cost_refined": cost_refined,
               "evaluations": nfev, "status": int(status), "converged": converged,
               "accepted": int(sum(accepted)), "seconds": time.perf_counter() - t0}
    log.info("refinement: %d points, %d + %d observations, %.2f px, offsets %.3g, cost %.1f -> "
             "%.1f, %d of %d joints accepted, %.1f s", n, len(tracks_a), len(tracks_b),
             problem.sigma_px, problem.sigma_d, cost_initial, cost_refined, sum(accepted),
             len(joints), summary["seconds"])
    return Refinement(out_joints, transforms, accepted, records, summary)


def _extent(points: np.ndarray) -> float:
    return float(np.ptp(points, axis=0).max()) if len(points) else 1.0


def _figures(j: Joint) -> dict:
    return {"axis_direction": [float(v) for v in j.axis_direction],
            "axis_point": [float(v) for v in j.axis_point], "motion": float(j.motion)}


def _uncertainty(b: _JointBlock, cov: np.ndarray, n_params: int) -> dict:
    """1-sigma figures of one joint from the global covariance: the axis direction's RMS angle
    (deg), the axis line's RMS offset normal to it (revolute) and the value's sigma."""
    o = b.offset
    ax = cov[o:o + 2, o:o + 2]
    rec = {"axis_deg": float(np.degrees(np.sqrt(max(np.trace(ax), 0.0))))}
    if b.type == "revolute":
        pt = cov[o + 2:o + 4, o + 2:o + 4]
        rec["position"] = float(np.sqrt(max(np.trace(pt), 0.0)))
        k = o + 4
    else:
        rec["position"] = None
        k = o + 2
    if b.leader is None:
        rec["state"] = float(np.sqrt(max(cov[k, k], 0.0)))
    else:
        rec["state"] = None
    return rec


def _link_transforms(kin: _Kinematics, joints: list[Joint], accepted: list[bool],
                     g: np.ndarray, base: Similarity, scale: float) -> list[Similarity]:
    """Each link's A -> B motion: the refined base's, composed down the tree with each joint kept
    (refined or initial)."""
    _, rots, trans = kin.motions(g)
    out: list[Similarity | None] = [None] * kin.n_links
    out[kin.root] = Similarity(rots[kin.root], trans[kin.root], scale)
    for b in kin.blocks:
        jt = joints[b.index]
        parent = out[b.parent]
        if jt.type == "revolute":
            K = skew(jt.axis_direction)
            v = jt.motion
            rj = np.eye(3) + np.sin(v) * K + (1 - np.cos(v)) * K @ K
            tj = jt.axis_point - rj @ jt.axis_point
        else:
            rj, tj = np.eye(3), jt.motion * jt.axis_direction
        out[b.child] = parent @ Similarity(rj, tj, 1.0)
    return [T if T is not None else Similarity() for T in out]

