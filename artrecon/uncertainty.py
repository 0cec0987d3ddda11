"""How precisely each SfM point is known, and the links' motions fitted with it.

A 3D-3D match pairs two triangulated points, one per configuration. Triangulation pins a point
across its viewing rays far better than along them: from views a few tens of degrees apart, a
pixel of image noise moves it several times further in depth than sideways (scraper_truck's and
scissors' matches: 3.4-5 x, median, in standard deviation), and how much depends on how many
views saw it and from where. Against the truth, these covariances explain the match residuals
far better than one isotropic noise (likelihood) at 0.1-0.2 px of image noise.

Least squares (Procrustes, isotropic) gives every direction of every match the same say; a thin
link, whose rotation about its length only its few matches' sideways offsets hold, then takes
the depth errors of its matches for a rotation (scraper_truck: the boom's 115 matches, 3 cm
across, rolled it 0.38 degrees and tilted both hinges' axes by 0.7-0.8; 0.12 and 0.24-0.27 with
the covariances).

:func:`point_covariances` gives each point's first-order covariance per unit image noise (pixels)
from its track (the cameras that saw it): ``(sum_i J_i^T J_i)^-1``, ``J_i`` the derivative of its
projection into view i. A match's residual ``T(p_a) - p_b`` then has covariance
``k^2 (s^2 R C_a R^T + C_b)``, ``k`` the image noise (unknown, estimated with the motions), plus
a small isotropic part (see :func:`robust_gls_transforms`). That function is the
maximum-likelihood fit of the links' motions (one common scale) under this model, with the
Cauchy tails of :func:`artrecon.procrustes.robust_shared_scale_transforms` (a multivariate
Student t with one degree of freedom on the Mahalanobis length of each residual): the
generalised least-squares counterpart of that fit, which it gives when every covariance is the
identity.

The covariances are first order in the given (or SfM-refined) camera poses: the poses' own errors
are not in them (with known poses they are exact to the noise of the arm's kinematics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artrecon.geometry import exp_so3, group_sums, skew
from artrecon.procrustes import Similarity, robust_shared_scale_transforms

__all__ = ["MatchCovariances", "point_covariances", "robust_gls_transforms",
           "MAX_GLS_ITERATIONS"]

#: Rounds of the robust GLS fit at most (each: weights, then one Gauss-Newton step of the
#: motions; it stops when the weights and the motions settle, a few tens of rounds).
MAX_GLS_ITERATIONS = 100
#: A point whose views leave a direction this many times less precise than its best one
#: (standard deviation; two nearly parallel rays) has that direction capped at this ratio, so
#: that the information matrix stays invertible; such a direction has next to no weight anyway.
MAX_ANISOTROPY = 1e3
#: Median of the chi-squared distribution with 3 degrees of freedom.
CHI2_3_MEDIAN = 2.366
#: Degrees of freedom of the Student t noise model (1: Cauchy, as the isotropic robust fit).
STUDENT_DOF = 1.0


@dataclass(frozen=True)
class MatchCovariances:
    """Triangulation covariances (:func:`point_covariances`, per unit image noise) of the points
    :func:`artrecon.articulation.articulate` is given, row for row."""

    matches_a: np.ndarray
    """(n, 3, 3) of the matches' points of A ..."""
    matches_b: np.ndarray
    """... and of B."""
    background_a: np.ndarray
    """(m, 3, 3) of the background matches' points of A ..."""
    background_b: np.ndarray
    """... and of B."""
    candidates_a: np.ndarray | None = None
    """(len(candidates[0]), 3, 3) of the guided matching's candidates of A ..."""
    candidates_b: np.ndarray | None = None
    """... and of B."""


def point_covariances(reconstruction, point_ids) -> np.ndarray:
    """First-order covariance (n, 3, 3) of SfM points per unit image noise (pixel^2).

    ``(sum_i J_i^T J_i)^-1`` over the point's track, ``J_i`` (2 x 3) the derivative of its pinhole
    projection into view i (the camera's focal lengths; lens distortion, a near-identity in the
    derivative, is left out). Units: the reconstruction's length unit squared per pixel squared.

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
    point_ids : (n,) int
        3D point ids of the reconstruction.
    """
    ids = np.asarray(point_ids, dtype=np.int64).reshape(-1)
    if len(ids) == 0:
        return np.zeros((0, 3, 3))
    image_ids = sorted(reconstruction.images)
    row = {iid: k for k, iid in enumerate(image_ids)}
    rots = np.zeros((len(image_ids), 3, 3))
    trans = np.zeros((len(image_ids), 3))
    focal = np.zeros((len(image_ids), 2))
    for k, iid in enumerate(image_ids):
        image = reconstruction.images[iid]
        camera = reconstruction.cameras[image.camera_id]
        m = image.cam_from_world().matrix()
        rots[k], trans[k] = m[:, :3], m[:, 3]
        focal[k] = camera.focal_length_x, camera.focal_length_y
    xyz = np.zeros((len(ids), 3))
    owner, view = [], []
    for n, pid in enumerate(ids):
        point = reconstruction.points3D[int(pid)]
        xyz[n] = point.xyz
        for el in point.track.elements:
            owner.append(n)
            view.append(row[el.image_id])
    owner, view = np.asarray(owner, np.int64), np.asarray(view, np.int64)
    xc = np.einsum("oij,oj->oi", rots[view], xyz[owner]) + trans[view]
    z = xc[:, 2]
    seen = z > 0
    owner, view, xc, z = owner[seen], view[seen], xc[seen], z[seen]
    proj = np.zeros((len(owner), 2, 3))
    proj[:, 0, 0] = focal[view, 0] / z
    proj[:, 0, 2] = -focal[view, 0] * xc[:, 0] / z ** 2
    proj[:, 1, 1] = focal[view, 1] / z
    proj[:, 1, 2] = -focal[view, 1] * xc[:, 1] / z ** 2
    jac = proj @ rots[view]  # (observations, 2, 3)
    info = group_sums(owner, np.einsum("oki,okj->oij", jac, jac).reshape(-1, 9), len(ids))
    return _inverse_information(info.reshape(-1, 3, 3))


def _inverse_information(info: np.ndarray) -> np.ndarray:
    """The covariances (n, 3, 3) of the informations ``info`` (n, 3, 3): each eigenvalue kept at
    least 1 / MAX_ANISOTROPY^2 of the largest; a point without information (no usable view)
    gets a huge isotropic covariance (nothing known). All at once: a Python loop of 3 x 3
    eigendecompositions was most of the matches stage's covariances (11 k points of truck A)."""
    vals, vecs = np.linalg.eigh(info)
    top = vals[:, -1:]
    vals = np.maximum(vals, top / MAX_ANISOTROPY ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):  # the points without: replaced below
        out = (vecs / vals[:, None, :]) @ np.swapaxes(vecs, 1, 2)
    out[~(top[:, 0] > 0)] = np.eye(3) * 1e12
    return out


def robust_gls_transforms(
    groups: list[tuple[np.ndarray, np.ndarray]],
    covariances: list[tuple[np.ndarray, np.ndarray]],
    populations: list[np.ndarray | None] | None = None,
    iterations: int = MAX_GLS_ITERATIONS,
) -> tuple[list[Similarity], list[np.ndarray], list[np.ndarray]]:
    """One similarity per group (one common scale), the maximum-likelihood fit when each pair's
    residual ``r = s R src + t - dst`` is Student-t distributed (one degree of freedom: Cauchy)
    with a covariance built from the two points' triangulation covariances: the generalised
    least-squares form of :func:`artrecon.procrustes.robust_shared_scale_transforms`.

    Noise model. Along each principal axis (eigenvector, eigenvalue ``e``) of the pair's
    triangulation covariance ``s^2 R C_src R^T + C_dst`` the residual's variance is ``a e + b``:
    ``a`` the image noise (pixel^2) that triangulation turns into 3D error, ``b`` an isotropic
    part it does not explain (the two configurations' features of one match are not quite the
    same physical point: fitted to scraper_truck's and scissors' matches against the truth, up to
    0.1 mm on the small moving links, beside 0.1-0.2 px of image noise; without it the scissors'
    moving half took a 0.2 degree roll). Each population (a link's matches; the background
    matches anchoring the base) has its own ``a`` and ``b``, estimated with the motions. With
    every covariance the identity this is the isotropic fit (a + b one noise scale).

    EM from the isotropic robust fit: each round weighs each pair by
    ``u = (nu + 3) / (nu + d^2)`` (``d`` its Mahalanobis length), re-estimates its population's
    ``a`` and ``b`` (a few Newton steps on the expected log-likelihood), then takes one
    Gauss-Newton step of all motions and the common scale together. Stops when no weight moves by
    more than 1e-6 and the step is below 1e-10 (rad, relative scale, translation in units of the
    groups' extent), or after ``iterations`` rounds.

    Parameters
    ----------
    groups : list of (src (n_k, 3), dst (n_k, 3))
    covariances : list of (C_src (n_k, 3, 3), C_dst (n_k, 3, 3))
        Each pair's point covariances, src's in its own frame (any common unit per population:
        only shapes and relative sizes matter, a and b absorb the rest).
    populations : list of (n_k,) int or None, optional
        Population of each pair (None: one per group).
    iterations : int

    Returns
    -------
    transforms : list of Similarity
    weights : list of (n_k,) float
        Each pair's final weight ``1 / (1 + d^2)`` (0-1], as the isotropic fit's.
    weight_matrices : list of (n_k, 3, 3) float
        Each pair's weight matrix in the last Gauss-Newton step: ``u`` times the inverse of its
        residual covariance (dst units); the information the pair gives about the motion.
    """
    if populations is None:
        populations = [None] * len(groups)
    if not (len(groups) == len(covariances) == len(populations)):
        raise ValueError("groups, covariances and populations must have one entry per group")
    src = [np.asarray(a, float) for a, _ in groups]
    dst = [np.asarray(b, float) for _, b in groups]
    cov_s = [np.asarray(c, float) for c, _ in covariances]
    cov_d = [np.asarray(c, float) for _, c in covariances]
    pops = [np.zeros(len(a), np.int64) if p is None else np.asarray(p) for a, p in
            zip(src, populations, strict=True)]
    for a, cs, cd, p in zip(src, cov_s, cov_d, pops, strict=True):
        if cs.shape != (len(a), 3, 3) or cd.shape != (len(a), 3, 3) or p.shape != (len(a),):
            raise ValueError(f"a group of {len(a)} pairs needs (n, 3, 3) covariances and (n,) "
                             "populations")
    start, _ = robust_shared_scale_transforms(list(zip(src, dst, strict=True)), pops)
    scale = start[0].scale
    rots = [T.rotation.copy() for T in start]
    trans = [T.translation.copy() for T in start]
    extent = max(float(np.ptp(b, axis=0).max()) for b in dst) or 1.0
    n_groups = len(src)
    noise: dict[tuple[int, int], np.ndarray] = {}  # (log a, log b) of each population

    def e_step(i: int, update: bool):
        """Pair weights, weight matrices and the Gauss-Newton terms of group i."""
        a, b, p = src[i], dst[i], pops[i]
        x = scale * a @ rots[i].T
        r = x + trans[i] - b
        shape = scale ** 2 * np.einsum("ij,njk,lk->nil", rots[i], cov_s[i], rots[i]) + cov_d[i]
        e, vecs = np.linalg.eigh(shape)
        e = np.maximum(e, 0.0)
        z2 = np.einsum("nji,nj->ni", vecs, r) ** 2  # residual along each principal axis
        u, w, var = np.empty(len(a)), np.empty(len(a)), np.empty((len(a), 3))
        for q in np.unique(p):
            m = p == q
            key = (i, int(q))
            if key not in noise:
                noise[key] = _start_noise(e[m], z2[m])
            d2 = np.sum(z2[m] / _variances(noise[key], e[m]), axis=1)
            u[m] = (STUDENT_DOF + 3) / (STUDENT_DOF + d2)  # E-step
            w[m] = 1.0 / (1.0 + d2)
            if update:
                noise[key] = _noise_m_step(noise[key], e[m], z2[m], u[m])  # M-step (noise)
            var[m] = _variances(noise[key], e[m])
        wmat = np.einsum("nij,nj,nkj->nik", vecs, u[:, None] / var, vecs)
        return x, r, w, wmat

    weights = [np.ones(len(a)) for a in src]
    for _ in range(iterations):
        h = np.zeros((6 * n_groups + 1, 6 * n_groups + 1))
        g = np.zeros(6 * n_groups + 1)
        new = []
        for i in range(n_groups):
            x, r, w, wmat = e_step(i, update=True)
            new.append(w)
            # r(delta) = r + omega x x + ds x + dt: d r / d(omega, dt, ds)
            jac = np.concatenate([-skew(x), np.broadcast_to(np.eye(3), (len(x), 3, 3)),
                                  x[:, :, None]], axis=2)  # (n, 3, 7)
            hi = np.einsum("nki,nkl,nlj->ij", jac, wmat, jac)
            gi = np.einsum("nki,nkl,nl->i", jac, wmat, r)
            sl = slice(6 * i, 6 * i + 6)
            h[sl, sl] += hi[:6, :6]
            h[sl, -1] += hi[:6, 6]
            h[-1, sl] += hi[6, :6]
            h[-1, -1] += hi[6, 6]
            g[sl] += gi[:6]
            g[-1] += gi[6]
        step = -np.linalg.solve(h, g)
        change = max(float(np.max(np.abs(a - b))) for a, b in zip(new, weights, strict=True))
        weights = new
        for i in range(n_groups):
            # the motion p -> (1 + ds) exp(omega) s R p + t + dt
            rots[i] = _orthonormal(exp_so3(step[6 * i:6 * i + 3]) @ rots[i])
            trans[i] = trans[i] + step[6 * i + 3:6 * i + 6]
        scale *= 1.0 + step[-1]
        per_group = step[:-1].reshape(-1, 6)
        moved = max(float(np.abs(per_group[:, :3]).max()),
                    float(np.abs(per_group[:, 3:]).max()) / extent, abs(float(step[-1])))
        if change < 1e-6 and moved < 1e-10:
            break
    final = [e_step(i, update=False) for i in range(n_groups)]
    transforms = [Similarity(r, t, scale) for r, t in zip(rots, trans, strict=True)]
    return transforms, [f[2] for f in final], [f[3] for f in final]


def _variances(params: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Each pair's variance along its principal axes: a e + b (``params`` = (log a, log b))."""
    return np.exp(params[0]) * e + np.exp(params[1])


def _start_noise(e: np.ndarray, z2: np.ndarray) -> np.ndarray:
    """(log a, log b) to start from: triangulation alone at its median Mahalanobis length,
    plus a tenth of it as the isotropic part at a typical pair's best-known direction."""
    a = max(float(np.median(np.sum(z2 / e, axis=1))) / CHI2_3_MEDIAN, 1e-300)
    b = max(0.1 * a * float(np.median(e[:, 0])), 1e-300)
    return np.log([a, b])


def _noise_m_step(params: np.ndarray, e: np.ndarray, z2: np.ndarray, u: np.ndarray
                  ) -> np.ndarray:
    """(log a, log b) maximising the expected log-likelihood
    -1/2 sum(log(a e + b) + u z^2 / (a e + b)) given the E-step's weights u (a few damped Newton
    steps from ``params``; a and b each at least 1e-12 of their sum's typical size)."""
    uz2 = u[:, None] * z2
    lo = np.log(1e-12) + max(params)

    def f(t):
        v = _variances(t, e)
        return 0.5 * float(np.sum(np.log(v) + uz2 / v))

    t = np.array(params, float)
    for _ in range(20):
        v = _variances(t, e)
        dv = np.stack([np.exp(t[0]) * e, np.broadcast_to(np.exp(t[1]), e.shape)])
        c1 = 1.0 / v - uz2 / v ** 2
        c2 = -1.0 / v ** 2 + 2.0 * uz2 / v ** 3
        grad = 0.5 * np.array([np.sum(c1 * dv[0]), np.sum(c1 * dv[1])])
        hess = 0.5 * np.array([[np.sum(c2 * dv[0] ** 2 + c1 * dv[0]), np.sum(c2 * dv[0] * dv[1])],
                               [np.sum(c2 * dv[0] * dv[1]), np.sum(c2 * dv[1] ** 2 + c1 * dv[1])]])
        f0, lam = f(t), 1e-6 * (abs(hess[0, 0]) + abs(hess[1, 1]) + 1e-300)
        for _ in range(30):  # Levenberg-Marquardt damping until the step goes downhill
            try:
                step = -np.linalg.solve(hess + lam * np.eye(2), grad)
            except np.linalg.LinAlgError:
                step = -grad / lam
            cand = np.maximum(t + np.clip(step, -5, 5), lo)
            if f(cand) <= f0:
                break
            lam *= 10
        else:
            break
        done = np.max(np.abs(cand - t)) < 1e-8
        t = cand
        if done:
            break
    return t


def _orthonormal(r: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(r)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
