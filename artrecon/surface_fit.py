"""Each moving link's A -> B motion refined against its dense surface as well as its matches.

The links' motions come from their 3D-3D matches (:func:`artrecon.link_motions.robust_refit`):
a few dozen to a few hundred SIFT points per link, each triangulated to a few tenths of a
millimetre. A long, narrow link (a scissor blade 14 mm wide, a handle, a boom) has its matches
nearly on a line, and the roll about that line rests on how their depths scatter across a width
of a centimetre or two: on scissors (seed 2) the moving half's 108 matches rolled it by 0.47
degrees, and the hinge's axis, which a 30 degree turn amplifies by 1 / (2 sin 15 deg), by 0.9.

The dense points hold what the matches lack: thousands of oriented points on the same link in
both configurations. Moved by the link's motion, A's points must lie on B's surface: a residual
along B's normal at the nearest B point of the same link (point to plane). That pins the motion
across the surface (roll, tilt, height: the directions the matches know least), and says
nothing along it, where the matches pin it. The two together, one Gauss-Newton problem per
link, 6 unknowns (rotation and translation; the configurations' common scale is held):

- the matches' term: each match's residual ``s R a + t - b`` weighed by its weight matrix from
  the robust refit (:attr:`artrecon.segment.Segmentation.precisions`: its robust weight times the
  inverse covariance of its residual), so that the surface term alone moves the motion away from
  the matches' own optimum;
- the surface's term: A's points of the link, moved, paired with their nearest B point of the
  link within :attr:`SurfaceConfig.reach` dense spacings whose normal agrees with the moved
  point's normal within :attr:`SurfaceConfig.max_normal_angle_deg` (a point of the other face
  of a thin part is no partner); each residual over the surface's robust noise (1.4826 MAD of
  the residuals), Cauchy-weighted, and the term scaled by :attr:`SurfaceConfig.weight`: the
  information one dense point carries, since neighbouring stereo points share their errors
  (they come from overlapping correlation windows);
- pairs found again at each iteration (iterative closest point), until the step is negligible.

The base (the link the background moves with) keeps its motion: the background's matches pin
it. A link with too few surface pairs keeps its matches' motion. :func:`surface_refit` reports
per link the pairs, the surface noise, and how far the motion moved.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from artrecon.geometry import exp_so3, point_spacing, rotation_angle, skew
from artrecon.link_motions import motion_rms
from artrecon.procrustes import Similarity
from artrecon.segment import Segmentation

log = logging.getLogger(__name__)

__all__ = ["SurfaceConfig", "surface_refit", "refit_link"]

#: The iterations stop when a step turns the link by less than this (rad) and moves it by less
#: than this many dense spacings.
STEP_TOLERANCE = 1e-9
#: Robust noise scale floor, as a fraction of the dense spacing (a perfect synthetic surface).
MIN_NOISE_FRACTION = 1e-3


@dataclass(frozen=True)
class SurfaceConfig:
    """Settings of the links' surface refit (:func:`surface_refit`)."""

    enabled: bool = True
    """Refine each moving link's motion against its dense surface (off: the matches' motion)."""
    weight: float = 0.3
    """Information of one dense point's residual relative to an independent one: stereo points
    share their errors with the neighbours of their correlation window (one independent point
    per 5 x 5 px block at 1.5 px spacing would be 0.09). Measured on the 30 runs of
    ``bench_gates --seeds 0-2`` (cached captures), the moving blade's rotation error on scissors
    seeds 0, 1, 2: 0.20, 0.22, 0.47 deg from the matches alone; 0.14, 0.12, 0.20 at 0.1; 0.08,
    0.10, 0.05 at 0.3; 0.03, 0.11, 0.08 at 1. At 0.3 every other moving link of the ten scenes
    stays within about 0.02 deg of its matches' error; at 1 pliers_panda seed 1 doubles (0.03 ->
    0.07). It is per point, so the term's pull grows with the dense resolution while the
    surface's own biases do not average out: the pliers scenes at full resolution (4-5 times the
    points, c721a29) have axes 0.029-0.281 deg over seeds 0-2 where the matches alone give
    0.014-0.184; a rotation floor on the term's information did not settle it (scissors lost
    its gain)."""
    reach: float = 4.0
    """Pair a moved A point with a B point at most this many dense spacings away (the median
    distance between B's neighbouring points)."""
    max_normal_angle_deg: float = 30.0
    """Pair only points whose normals (A's moved) agree within this angle."""
    loss_scale: float = 3.0
    """Cauchy scale of the surface residuals, in robust standard deviations."""
    iterations: int = 50
    """Gauss-Newton / closest-point rounds at most (scissors' blade, the slowest seen, converges
    in 21)."""
    min_pairs: int = 50
    """A link with fewer surface pairs keeps its matches' motion."""


def surface_refit(seg: Segmentation, root: int | None, points_a: np.ndarray,
                  points_b: np.ndarray, dense_a, dense_b, labels_a: np.ndarray,
                  labels_b: np.ndarray, config: SurfaceConfig = SurfaceConfig()
                  ) -> tuple[Segmentation, list[dict]]:
    """Every link's motion but the base's refined against its matches and its dense surface.

    Parameters
    ----------
    seg : Segmentation
        After the robust refit (its ``precisions``, else ``weights`` and ``rms``, weigh the
        matches).
    root : int or None
        The base link, kept as it is.
    points_a, points_b : (n, 3) float
        The matches seg labels.
    dense_a, dense_b : DensePoints
        Each configuration's oriented points.
    labels_a, labels_b : (m_a,), (m_b,) int
        Each dense point's link (-1: none).
    config : SurfaceConfig

    Returns
    -------
    seg : Segmentation
        With the refined transforms, their members' RMS residuals and each link's surface
        information (``surface_information`` (n_links, 6, 6), ``surface_gradient``
        (n_links, 6): the surface term's Gauss-Newton matrix and gradient at the refined
        motion, in the parameters of :func:`artrecon.confidence._batch_gls_step`; zero for the
        links kept), which the joints' bootstrap adds to each resample of the matches.
    reports : list of dict
        Per link: ``link``, ``pairs``, ``surface_noise`` (B units), ``rotation_change_deg``,
        ``translation_change`` (B units), ``iterations``, ``applied`` and, when not, ``reason``.
    """
    if not config.enabled:
        return seg, []
    spacing = point_spacing(dense_b.points) or 1.0  # 1.0: too few points to tell
    transforms = list(seg.transforms)
    information = np.zeros((seg.n_links, 6, 6))
    gradient = np.zeros((seg.n_links, 6))
    reports = []
    labels = np.asarray(seg.labels)
    for k in range(seg.n_links):
        if k == root:
            continue
        members = labels == k
        weights = _match_weights(seg, k, members)
        T, report, prior = refit_link(
            transforms[k], points_a[members], points_b[members], weights,
            dense_a.points[labels_a == k], dense_a.normals[labels_a == k],
            dense_b.points[labels_b == k], dense_b.normals[labels_b == k], spacing, config)
        report["link"] = k
        reports.append(report)
        log.info("surface refit: link %d %s (%d surface pairs, noise %.3g; turned %.3g deg, "
                 "moved %.3g)", k, "refined" if report["applied"] else
                 f"kept ({report.get('reason')})", report["pairs"], report["surface_noise"],
                 report["rotation_change_deg"], report["translation_change"])
        transforms[k] = T
        if prior is not None:
            information[k], gradient[k] = prior
    rms = [motion_rms(T, points_a[labels == k], points_b[labels == k]) for k, T in
           enumerate(transforms)]
    return replace(seg, transforms=transforms, rms=rms, surface_information=information,
                   surface_gradient=gradient), reports


def refit_link(T: Similarity, match_a: np.ndarray, match_b: np.ndarray,
               match_weights: np.ndarray, surf_a: np.ndarray, normals_a: np.ndarray,
               surf_b: np.ndarray, normals_b: np.ndarray, spacing: float,
               config: SurfaceConfig = SurfaceConfig()
               ) -> tuple[Similarity, dict, tuple | None]:
    """One link's motion ``T`` refined against its matches and its dense surface.

    Parameters
    ----------
    T : Similarity
        The matches' motion (the start; its scale is held).
    match_a, match_b : (n, 3) float
        The link's matches.
    match_weights : (n, 3, 3) float
        Each match's weight matrix (inverse residual covariance, B units).
    surf_a, normals_a : (p, 3) float
        The link's dense points and unit normals in A.
    surf_b, normals_b : (q, 3) float
        The same in B.
    spacing : float
        The dense points' spacing (B units): the unit of :attr:`SurfaceConfig.reach`.

    Returns
    -------
    T : Similarity
        Refined, or ``T`` itself when too few surface pairs are found.
    report : dict
        ``pairs``, ``surface_noise``, ``rotation_change_deg``, ``translation_change``,
        ``iterations``, ``applied`` (and ``reason`` when not).
    prior : (information (6, 6), gradient (6,)) or None
        The surface term's Gauss-Newton matrix and gradient at the refined motion (rotation
        perturbed on the left about the origin, translation added: the parameters of
        :func:`artrecon.confidence._batch_gls_step`); None when the motion was kept.
    """
    report = {"pairs": 0, "surface_noise": float("nan"), "rotation_change_deg": 0.0,
              "translation_change": 0.0, "iterations": 0, "applied": False}
    if len(surf_a) < config.min_pairs or len(surf_b) < config.min_pairs:
        report["reason"] = f"fewer than {config.min_pairs} dense points in A or B"
        return T, report, None
    roots = _sqrt_weights(match_weights)  # (n, 3, 3): W^T W = weight matrix
    tree = cKDTree(surf_b)
    reach = config.reach * spacing
    cos_max = np.cos(np.radians(config.max_normal_angle_deg))
    rot, trans, scale = np.asarray(T.rotation, float), np.asarray(T.translation, float), T.scale
    step_norm = np.inf
    for it in range(config.iterations + 1):
        x = scale * match_a @ rot.T  # the motion's rotation acts about the origin; t is added
        surface = _surface_rows(scale * surf_a @ rot.T, trans, normals_a @ rot.T, tree,
                                surf_b, normals_b, reach, cos_max, config, spacing)
        if surface is None or len(surface[0]) < config.min_pairs:
            pairs = 0 if surface is None else len(surface[0])
            report["reason"] = f"{pairs} surface pairs, fewer than {config.min_pairs}"
            return T, {**report, "pairs": pairs}, None
        rows_s, res_s, noise = surface
        if it == config.iterations or step_norm < STEP_TOLERANCE:
            break  # the surface's information at the solution, for the bootstrap
        jac = np.zeros((len(x), 3, 6))
        jac[:, :, :3] = -skew(x)
        jac[:, :, 3:] = np.eye(3)
        rows_m = np.einsum("nij,njk->nik", roots, jac).reshape(-1, 6)
        res_m = np.einsum("nij,nj->ni", roots, x + trans - match_b).reshape(-1)
        step = np.linalg.lstsq(np.vstack([rows_m, rows_s]), -np.r_[res_m, res_s], rcond=None)[0]
        rot, trans = exp_so3(step[:3]) @ rot, trans + step[3:]
        report["iterations"] = it + 1
        step_norm = max(float(np.linalg.norm(step[:3])), float(np.linalg.norm(step[3:])) / spacing)
    refined = Similarity(rot, trans, scale)
    report.update(pairs=len(rows_s), surface_noise=noise, applied=True,
                  rotation_change_deg=float(np.degrees(rotation_angle(
                      rot @ np.asarray(T.rotation, float).T))),
                  translation_change=float(np.linalg.norm(
                      refined.apply(match_a).mean(0) - T.apply(match_a).mean(0)))
                  if len(match_a) else 0.0)
    return refined, report, (rows_s.T @ rows_s, rows_s.T @ res_s)


def _surface_rows(y, trans, normals, tree, surf_b, normals_b, reach, cos_max,
                  config: SurfaceConfig, spacing: float):
    """The surface term's rows and residuals (whitened, robust-weighted, scaled by the weight)
    for A's points rotated (``y``, without the translation ``trans``) and their normals; None
    when no point finds a partner. Also the surface's robust noise."""
    dist, idx = tree.query(y + trans, distance_upper_bound=reach)
    ok = np.isfinite(dist)
    ok[ok] &= np.einsum("ij,ij->i", normals[ok], normals_b[idx[ok]]) > cos_max
    if not ok.any():
        return None
    y, q, n = y[ok], surf_b[idx[ok]], normals_b[idx[ok]]
    rho = np.einsum("ij,ij->i", n, y + trans - q)
    centre = float(np.median(rho))
    noise = max(1.4826 * float(np.median(np.abs(rho - centre))), MIN_NOISE_FRACTION * spacing)
    robust = 1.0 / (1.0 + (rho / (config.loss_scale * noise)) ** 2)
    scale_rows = np.sqrt(config.weight * robust) / noise
    return np.c_[np.cross(y, n), n] * scale_rows[:, None], rho * scale_rows, noise


def _match_weights(seg: Segmentation, k: int, members: np.ndarray) -> np.ndarray:
    """Link k's matches' weight matrices: the robust refit's, else its weights over its RMS."""
    if seg.precisions is not None:
        return np.asarray(seg.precisions, float)[members]
    w = np.ones(int(members.sum())) if seg.weights is None else \
        np.asarray(seg.weights, float)[members]
    rms = seg.rms[k] if seg.rms and seg.rms[k] > 0 else 1.0
    return w[:, None, None] * np.eye(3) / rms ** 2


def _sqrt_weights(weights: np.ndarray) -> np.ndarray:
    """Square roots ``W`` (W^T W = weight matrix) of symmetric positive semi-definite 3 x 3s."""
    e, v = np.linalg.eigh(weights)
    return np.sqrt(np.maximum(e, 0.0))[:, :, None] * np.swapaxes(v, 1, 2)
