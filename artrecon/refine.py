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

The background's matches (the room the base stands in) join the problem as points of the base,
as they anchor the base in the links' fit. The noise levels are estimated with the solution, per
population (each link's matches, the background's): the image noise ``s_px`` robustly from the
reprojection residuals of both configurations, the offsets' spread ``s_d`` by MacKay's evidence
update (the offsets' squared lengths over their well-determined dimensions), over a few rounds
of solving. The joints' covariance is the inverse of the Gauss-Newton information with the
points and offsets marginalised (Schur complement), scaled by the reduced chi-square when above
1: each joint's 1-sigma figures (axis angle, axis line position, value) are written to its
record (``Joint.confidence["refinement"]``) and the harness scores them.

Solver (:mod:`artrecon.refine_solver`, the problem's residuals and normal equations too):
Levenberg-Marquardt with the points and offsets eliminated per match (6 x 6 blocks), as a bundle
adjuster does; analytic derivatives in the points and offsets, central differences in the few
global parameters (the base's motion and the joints). This module holds the articulated side:
the parameter layout and the links' motions from it, the noise levels' estimation, the
uncertainty and the acceptance.

Acceptance (the refinement replaces nothing it does not beat): a joint may take its refined
figures only when the solver converged, the refined motion keeps the joint's direction of
motion, and the refined axis lies within the initial estimate's own uncertainty (its bootstrap
spread, :mod:`artrecon.confidence`), widened by the refined one: ``angle(refined, initial) <= k
* hypot(spread_initial, sigma_refined)`` (``k`` = :attr:`RefineConfig.max_change_sigma`); and
only with :attr:`RefineConfig.adopt` on. It is off by default: measured on the ten bundled
scenes, the refined axes were not better than the matches' fit (see the setting), so by default
the refinement reports, the joints stay.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np

from artrecon.geometry import exp_so3, rotation_about
from artrecon.model import Joint
from artrecon.procrustes import Similarity
from artrecon.refine_solver import Problem, Tracks, Views, covariance, extent, solve

log = logging.getLogger(__name__)

__all__ = ["RefineConfig", "Views", "Tracks", "Refinement", "refine_joints", "tracks_of",
           "views_of", "map_record"]

#: Observations per configuration a match needs to enter the problem.
MIN_OBSERVATIONS = 2
#: The image noise is estimated no lower than this (pixels): the synthetic images' features are
#: no better than a few hundredths of a pixel.
MIN_SIGMA_PX = 0.02
#: Median of the chi-squared distribution with 3 degrees of freedom.
CHI2_3_MEDIAN = 2.366


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the articulated bundle adjustment (:func:`refine_joints`)."""

    enabled: bool = True
    """Refine the joints against the images (off: the joints from the matches' motions)."""
    loss_scale: float = 3.0
    """Cauchy scale of the residuals, in standard deviations."""
    rounds: int = 3
    """Expectation-maximisation rounds (solve, then re-estimate the noise levels)."""
    max_iterations: int = 50
    """Levenberg-Marquardt iterations per solve at most."""
    max_change_sigma: float = 3.0
    """A refined axis may move from the initial one by at most this many combined standard
    deviations (the initial's bootstrap spread and the refined one's, in quadrature)."""
    adopt: bool = False
    """Replace a joint by its refined figures where the checks pass. Off by default: over the ten
    bundled scenes (seed 0) the refined axes were worse than the matches' fit in 9 of 13 joints
    (median 0.058 against 0.028 deg), so the joints stay; the refinement's uncertainty and
    figures are reported beside them (``Joint.confidence["refinement"]``)."""


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
        self.length_params = {3, 4, 5}  # the base's translation; the axis points' offsets below
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
            if jt.type == "revolute":
                self.length_params |= {offset + 2, offset + 3}
            elif leader is None:
                self.length_params.add(offset + 2)
            self.blocks.append(block)
            offset = self.params(block).stop
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
                rj = rotation_about(u, v)
                tj = q - rj @ q
            else:
                rj, tj = np.eye(3), v * u
            rots[b.child] = rots[b.parent] @ rj
            trans[b.child] = scale * rots[b.parent] @ tj + trans[b.parent]
        return scale, rots, trans

    def params(self, block: _JointBlock) -> slice:
        """The global parameters of one joint (offsets from its initial figures)."""
        count = (4 if block.type == "revolute" else 2) + (0 if block.leader is not None else 1)
        return slice(block.offset, block.offset + count)

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


def _image_noise(problem: Problem, ra: np.ndarray, rb: np.ndarray, pops: np.ndarray) -> None:
    """Each population's image noise (pixels, robust: 1.4826 times the median absolute residual
    coordinate of its observations in both configurations: the same surface seen by the same
    camera; B's alone would take the offsets for image noise), set on the observations."""
    group = np.repeat(np.r_[pops[problem.ta.point], pops[problem.tb.point]], 2)
    spread = np.maximum(1.4826 * _median_by(group, np.abs(np.r_[ra.ravel(), rb.ravel()])),
                        MIN_SIGMA_PX)[::2]
    problem.sig_a, problem.sig_b = spread[:len(problem.ta)], spread[len(problem.ta):]


def _median_by(index: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each element's group median: ``index`` (n,) groups 0..k-1, ``values`` (n,)."""
    out = np.zeros(len(values))
    for k in np.unique(index):
        sel = index == k
        out[sel] = np.median(values[sel])
    return out


def refine_joints(points_a: np.ndarray, labels: np.ndarray, tracks_a: Tracks, tracks_b: Tracks,
                  views_a: Views, views_b: Views, joints: list[Joint], root: int,
                  base: Similarity, n_links: int, *, scale_known: bool,
                  points_b: np.ndarray | None = None,
                  populations: np.ndarray | None = None,
                  couplings: dict[int, tuple[int, float]] | None = None,
                  config: RefineConfig = RefineConfig()) -> Refinement:  # noqa: B008
    """The joints refined by articulated bundle adjustment (see the module's docstring).

    Parameters
    ----------
    points_a : (n, 3)
        The matches' points in A's frame (their starting positions).
    labels : (n,) int
        Link of each match (-1: an outlier, left out).
    points_b : (n, 3), optional
        The matches' points in B's frame: their disagreement with the initial motions is where
        the offsets' spread starts (else 1e-3 of the object's extent).
    populations : (n,) int, optional
        Each match's population, which has its own offsets' spread (default: its link; the
        background matches anchoring the base are another population).
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
    populations = labels if populations is None else np.asarray(populations, np.int64)
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
    problem = Problem(kin, points_a[use], labels[use], tracks_a, tracks_b, views_a, views_b,
                       config.loss_scale)
    n, G = problem.n, kin.n_params
    g, X, d = np.zeros(G), points_a[use].copy(), np.zeros((n, 3))
    # the noise levels to begin with: the reprojection errors of the initial model, and the
    # matches' disagreement with their link's initial motion (an upper bound of the offsets)
    ra, rb = problem.pixels(g, X, d)
    pops = np.unique(populations[use], return_inverse=True)[1]
    _image_noise(problem, ra, rb, pops)
    floor_d = extent(X) * 1e-7
    if points_b is not None:
        miss = np.abs(problem._b_points(g, X, d) - np.asarray(points_b, float)[use])
        problem.sigma_d = np.maximum(1.4826 * _median_by(pops, np.median(miss, axis=1)), floor_d)
    else:
        problem.sigma_d = np.full(n, max(extent(X) * 1e-3, floor_d))
    iterations, converged = 0, False
    for _ in range(max(1, config.rounds)):
        g, X, d, cost, its, converged = solve(problem, g, X, d, config)
        iterations += its
        # EM: the image noise from the reprojection residuals (robust), the offsets' spread from
        # their estimates and their posterior variance
        _, cov_p = covariance(problem, g, X, d)
        ra, rb = problem.pixels(g, X, d)
        _image_noise(problem, ra, rb, pops)
        # the offsets' spread per population by MacKay's evidence update: |d|^2 over the
        # offsets' well-determined dimensions (gamma = 3 - tr(C_d) / s_d^2: an offset the
        # images cannot tell from the point's own depth error counts for little), robustly
        # (|d|^2 / s_d^2 of a well-determined offset is chi-squared with 3 degrees of freedom)
        post = np.einsum("nii->n", cov_p[:, 3:, 3:])
        gamma = np.clip(3.0 - post / problem.sigma_d ** 2, 1e-3, 3.0)
        spread = (_median_by(pops, np.sum(d * d, axis=1))
                  / (CHI2_3_MEDIAN * _median_by(pops, gamma) / 3.0))
        problem.sigma_d = np.maximum(np.sqrt(spread), floor_d)
    # the final solution and covariance at the final noise levels
    g, X, d, cost_refined, its, converged = solve(problem, g, X, d, config)
    iterations += its
    cov_g, _ = covariance(problem, g, X, d)
    ra, rb = problem.pixels(g, X, d)
    s2 = np.r_[np.sum(ra * ra, 1) / problem.sig_a ** 2, np.sum(rb * rb, 1) / problem.sig_b ** 2]
    weighted = float(np.sum(s2 / (1 + s2 / problem.c2))
                     + np.sum(d * d / problem.sigma_d[:, None] ** 2))
    dof = max(2 * (len(tracks_a) + len(tracks_b)) - 3 * n - G, 1)
    chi2 = weighted / dof
    cov_g = cov_g * max(1.0, chi2)  # scaled by the reduced chi-square when above 1
    # the initial model's cost at the final noise levels (points as triangulated, no offsets)
    cost_initial = problem.cost(np.zeros(G), points_a[use], np.zeros((n, 3)))
    status = "converged" if converged else f"stopped after {config.max_iterations} iterations"
    scale, rots, trans = kin.motions(g)
    refined = kin.joints_at(g, joints, scale, rots, trans)
    converged = bool(converged and np.all(np.isfinite(g)))
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
            verdict = f"not converged ({status})"
        elif not same_sign:
            verdict = "the refined motion reverses the joint's direction"
        elif not change <= allowed:
            verdict = (f"the axis moved {change:.3f} deg, beyond {allowed:.3f} deg "
                       f"({config.max_change_sigma:g} sigma of the initial's bootstrap spread "
                       "and the refined uncertainty)")
        elif not config.adopt:
            verdict = ("kept the initial joint (refine.adopt is off): the refined one passed "
                       "its checks")
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
    # the links' motions from the joints kept: the refined base, the joints not kept at their
    # initial figures (their parameters are offsets from them)
    kept = g.copy()
    for b in kin.blocks:
        if not accepted[b.index]:
            kept[kin.params(b)] = 0.0
    scale_kept, rots_kept, trans_kept = kin.motions(kept)
    transforms = [Similarity(r, t, scale_kept) for r, t in zip(rots_kept, trans_kept,
                                                                strict=True)]
    summary = {"points": n, "observations_a": len(tracks_a), "observations_b": len(tracks_b),
               "sigma_px": float(np.median(np.r_[problem.sig_a, problem.sig_b])),
               "sigma_offset": {int(p): float(problem.sigma_d[np.flatnonzero(
                   populations[use] == p)[0]]) for p in np.unique(populations[use])},
               "chi2_reduced": chi2, "cost_initial": cost_initial, "cost_refined": cost_refined,
               "iterations": iterations, "converged": converged,
               "accepted": int(sum(accepted))}  # its seconds: the model's timings["refine"]
    log.info("refinement: %d points, %d + %d observations, %.2f px, offsets %.3g, cost %.1f -> "
             "%.1f, %d of %d joints accepted, %.1f s", n, len(tracks_a), len(tracks_b),
             float(np.median(np.r_[problem.sig_a, problem.sig_b])),
             float(np.median(problem.sigma_d)), cost_initial, cost_refined,
             sum(accepted),
             len(joints), time.perf_counter() - t0)
    return Refinement(out_joints, transforms, accepted, records, summary)


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


def map_record(record: dict, T: Similarity, joint_type: str) -> dict:
    """A joint's refinement record (``Joint.confidence["refinement"]``) in another frame: its
    axes and points mapped by the similarity ``T`` (a registration), its lengths scaled
    (revolute states are angles and stay)."""
    if not record:
        return record
    out = dict(record)
    s = T.scale
    for key in ("refined", "initial"):
        if isinstance(out.get(key), dict):
            f = dict(out[key])
            f["axis_direction"] = [float(v) for v in T.rotation @ np.asarray(f["axis_direction"])]
            f["axis_point"] = [float(v) for v in T.apply(np.asarray(f["axis_point"])[None])[0]]
            if joint_type == "prismatic":
                f["motion"] = f["motion"] * s
            out[key] = f
    if out.get("position") is not None:
        out["position"] = out["position"] * s
    if joint_type == "prismatic" and out.get("state") is not None:
        out["state"] = out["state"] * s
    return out
