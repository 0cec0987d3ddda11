"""The least-squares machinery of the articulated bundle adjustment (:mod:`artrecon.refine`):
the cameras and observations, the robust problem over the matched points, their offsets and a
few global parameters, and its Levenberg-Marquardt solver with the points eliminated.

:class:`Problem` holds the residuals (reprojection errors of each match's point in A's images
and of its moved point in B's, over each observation's image noise; each match's offset over
its spread; Cauchy-robust), their Jacobians (analytic in the points and offsets, central
differences in the globals) and the normal equations with the points eliminated per match (the
Schur complement, 6 x 6 blocks), as a bundle adjuster does. How the globals move the links is
the caller's: ``kin`` (the kinematic layout of :mod:`artrecon.refine`) gives each link's motion
(``motions(g)``), the number of globals (``n_params``) and which of them are lengths
(``length_params``, for the finite-difference steps). :func:`solve` is the damped solver,
:func:`covariance` the globals' covariance with the points marginalised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

#: A Levenberg-Marquardt step that lowers the cost by less than this share of it ends the solve.
CONVERGED_DECREASE = 1e-6


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


class Problem:
    """The least-squares problem: residuals, their Jacobians (analytic in the points and offsets,
    central differences in the few global parameters) and the normal equations with the points
    eliminated (Schur complement), as in a bundle adjuster."""

    def __init__(self, kin, points: np.ndarray, labels: np.ndarray,
                 tracks_a: Tracks, tracks_b: Tracks, views_a: Views, views_b: Views,
                 loss_scale: float):
        self.kin, self.labels = kin, labels
        self.n = len(points)
        self.points0 = points
        self.ta, self.tb, self.va, self.vb = tracks_a, tracks_b, views_a, views_b
        self.fa = views_a.focal[tracks_a.view]
        self.fb = views_b.focal[tracks_b.view]
        self.c2 = loss_scale ** 2
        self.sig_a = np.full(len(tracks_a), 0.5)  # image noise (px) per observation: its
        self.sig_b = np.full(len(tracks_b), 0.5)  # configuration's and population's
        self.sigma_d = np.full(len(points), 1e-4)  # per match: its population's
        self.step = 1e-6 * max(extent(points), 1e-12)  # finite-difference step, lengths
        self.sum_a = aggregator(tracks_a.point, len(points))
        self.sum_b = aggregator(tracks_b.point, len(points))

    # --- residuals
    def _b_points(self, g: np.ndarray, X: np.ndarray, d: np.ndarray) -> np.ndarray:
        scale, rots, trans = self.kin.motions(g)
        lab = self.labels
        return scale * apply_rows(rots[lab], X) + trans[lab] + d

    def pixels(self, g, X, d) -> tuple[np.ndarray, np.ndarray]:
        """Pixel residuals (k, 2) of A's and B's observations."""
        ra = project(self.va, self.ta, X)[0] - self.ta.uv
        rb = project(self.vb, self.tb, self._b_points(g, X, d))[0] - self.tb.uv
        return ra * self.fa[:, None], rb * self.fb[:, None]

    def cost(self, g, X, d) -> float:
        ra, rb = self.pixels(g, X, d)
        s2 = np.r_[np.sum(ra * ra, 1) / self.sig_a ** 2, np.sum(rb * rb, 1) / self.sig_b ** 2]
        return float(0.5 * self.c2 * np.sum(np.log1p(s2 / self.c2))
                     + 0.5 * np.sum(d * d / self.sigma_d[:, None] ** 2))

    # --- normal equations
    def normal_equations(self, g, X, d, with_globals: bool = True):
        """Gauss-Newton blocks with Cauchy (IRLS) weights: per match the (6, 6) block of
        (X_i, d_i) and its right-hand side, their (6, G) coupling to the globals, the globals'
        (G, G) block and right-hand side."""
        n, G = self.n, self.kin.n_params
        # A: only the points
        pa, ja = project(self.va, self.ta, X)
        ra = (pa - self.ta.uv) * (self.fa / self.sig_a)[:, None]
        JXa = (self.fa / self.sig_a)[:, None, None] * (ja @ self.va.rotations[self.ta.view])
        wa = 1.0 / (1.0 + np.sum(ra * ra, 1) / self.c2)
        # B: the points, the offsets and the globals
        Y = self._b_points(g, X, d)
        pb, jb = project(self.vb, self.tb, Y)
        rb = (pb - self.tb.uv) * (self.fb / self.sig_b)[:, None]
        Jy = (self.fb / self.sig_b)[:, None, None] * (jb @ self.vb.rotations[self.tb.view])
        scale, rots, _ = self.kin.motions(g)
        pt = self.tb.point
        JXb = Jy @ (scale * rots[self.labels[pt]])
        wb = 1.0 / (1.0 + np.sum(rb * rb, 1) / self.c2)
        H = np.zeros((n, 6, 6))
        bp = np.zeros((n, 6))
        JXaw = (JXa * wa[:, None, None]).transpose(0, 2, 1)  # (ka, 3, 2)
        H[:, :3, :3] += self.sum_a(JXaw @ JXa)
        bp[:, :3] -= self.sum_a(apply_rows(JXaw, ra))
        Jb = np.concatenate([JXb, Jy], axis=2)  # (kb, 2, 6)
        Jbw = (Jb * wb[:, None, None]).transpose(0, 2, 1)  # (kb, 6, 2)
        H += self.sum_b(Jbw @ Jb)
        bp -= self.sum_b(apply_rows(Jbw, rb))
        H[:, 3:, 3:] += np.eye(3) / self.sigma_d[:, None, None] ** 2
        bp[:, 3:] -= d / self.sigma_d[:, None] ** 2
        if not with_globals:
            return H, bp, None, None, None
        dY = np.zeros((G, n, 3))
        for j in range(G):
            h = self._step(j)
            e = np.zeros(G)
            e[j] = h
            dY[j] = (self._b_points(g + e, X, d) - self._b_points(g - e, X, d)) / (2 * h)
        Jg = Jy @ dY[:, pt].transpose(1, 2, 0)  # (kb, 2, G)
        Hpg = self.sum_b(Jbw @ Jg)
        Jgw = (Jg * wb[:, None, None]).reshape(-1, G)
        Hgg = Jgw.T @ Jg.reshape(-1, G)
        bg = -(Jgw.T @ rb.reshape(-1))
        return H, bp, Hpg, Hgg, bg

    def _step(self, j: int) -> float:
        """Finite-difference step of global parameter j: lengths (translations, axis points)
        scale with the points' extent, angles and log-scales do not."""
        return self.step if j in self.kin.length_params else 1e-6


def apply_rows(mats: np.ndarray, vecs: np.ndarray) -> np.ndarray:
    """Row-wise products: (k, a, b) matrices times (k, b) vectors, (k, a)."""
    return (mats @ vecs[:, :, None])[:, :, 0]


def aggregator(index: np.ndarray, n: int):
    """A function summing (k, ...) values per ``index`` (k,) in [0, n): a sparse (n, k) sum,
    built once per set of observations."""
    k = len(index)
    M = sparse.csr_matrix((np.ones(k), (index, np.arange(k))), shape=(n, k))

    def total(values: np.ndarray) -> np.ndarray:
        return np.asarray(M @ values.reshape(k, -1)).reshape((n,) + values.shape[1:])

    return total


def project(views: Views, tracks: Tracks, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates (k, 2) of the observed points and their derivative (k, 2, 3)
    in the camera frame."""
    xc = apply_rows(views.rotations[tracks.view], X[tracks.point]) + views.translations[tracks.view]
    z = xc[:, 2]
    z = np.where(np.abs(z) < 1e-9, 1e-9, z)
    jac = np.zeros((len(xc), 2, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0 / z
    jac[:, 0, 2] = -xc[:, 0] / z ** 2
    jac[:, 1, 2] = -xc[:, 1] / z ** 2
    return xc[:, :2] / z[:, None], jac


def solve(problem: Problem, g: np.ndarray, X: np.ndarray, d: np.ndarray,
           config, with_globals: bool = True):
    """Levenberg-Marquardt with the points eliminated; returns (g, X, d, cost, iterations,
    converged)."""
    cost = problem.cost(g, X, d)
    lam = 1e-4
    converged = False
    it = 0
    while it < config.max_iterations:
        it += 1
        H, bp, Hpg, Hgg, bg = problem.normal_equations(g, X, d, with_globals)
        improved = False
        while lam < 1e12:
            Hd = H + lam * np.einsum("nii->ni", H)[:, :, None] * np.eye(6)
            Hinv = np.linalg.inv(Hd)
            if with_globals:
                flat = Hpg.reshape(-1, len(g))
                S = Hgg + lam * np.diag(np.diag(Hgg)) - flat.T @ (Hinv @ Hpg).reshape(-1, len(g))
                rhs = bg - flat.T @ apply_rows(Hinv, bp).reshape(-1)
                dg = np.linalg.lstsq(S, rhs, rcond=None)[0]
                dp = apply_rows(Hinv, bp - Hpg @ dg)
            else:
                dg = np.zeros_like(g)
                dp = apply_rows(Hinv, bp)
            g1, X1, d1 = g + dg, X + dp[:, :3], d + dp[:, 3:]
            c1 = problem.cost(g1, X1, d1)
            if np.isfinite(c1) and c1 <= cost:
                improved = True
                small = cost - c1 <= CONVERGED_DECREASE * max(cost, 1e-300)
                g, X, d, cost = g1, X1, d1, c1
                lam = max(lam / 10, 1e-12)
                break
            lam *= 10
        if not improved or small:
            converged = True  # no step lowers the cost any more: a minimum
            break
    return g, X, d, cost, it, converged


def covariance(problem: Problem, g, X, d) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of the global parameters with the points and offsets marginalised (the
    inverse of the Schur complement of the Gauss-Newton information), and each match's (6, 6)
    conditional covariance of (X_i, d_i)."""
    H, _, Hpg, Hgg, _ = problem.normal_equations(g, X, d)
    Hinv = np.linalg.inv(H)
    G = Hgg.shape[0]
    S = Hgg - Hpg.reshape(-1, G).T @ (Hinv @ Hpg).reshape(-1, G)
    return np.linalg.pinv(S), Hinv


def extent(points: np.ndarray) -> float:
    return float(np.ptp(points, axis=0).max()) if len(points) else 1.0
