"""Rigid-link segmentation of 3D-3D matches by sequential RANSAC over triplets.

Given matches (points_a[i] in configuration A, points_b[i] in configuration B), find the rigid
links: groups of matches that one similarity transform A -> B explains. As in the method, RANSAC
draws triplets, fits a Procrustes similarity to each, keeps the best transform, takes its inliers
as a link, removes them and repeats until no transform explains enough matches. Beyond the
method's fixed 1000-hypothesis loop:

- hypotheses are fitted and scored in batches with numpy (MSAC score, on a random subset of at
  most `score_subset` matches; the winner is re-scored on all matches);
- the number of hypotheses adapts to the inlier ratio, N = log(1 - p) / log(1 - w^3);
- degenerate (nearly collinear) triplets are skipped;
- every link is refined on all its inliers, with an inlier distance that shrinks to the noise
  level (so chance outliers do not bias it); after the first link the common scale is fixed;
- at the end every match is re-assigned to the link that explains it best (sequential extraction
  lets an early link steal matches near a joint), links are refitted jointly with one common
  similarity scale, and links smaller than the minimum size are dissolved into outliers (-1);
- the whole search runs `restarts` times from independent draws and the run that explains the
  matches best is kept (:func:`select_run`): which borderline matches one run admits decides
  the transform of a link whose matches barely constrain it (a long, thin link: the roll about
  its length), and through it the joint axis.

Thresholds are relative to the scene size (`artrecon.tolerances`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from artrecon import tolerances as tol
from artrecon.errors import DegenerateError, NoMotionError, SingleBodyError
from artrecon.procrustes import (
    Similarity,
    batch_similarity_transforms,
    rigid_transform,
    rotation_angle,
    shared_scale_transforms,
    similarity_transform,
)
from artrecon.workers import side_by_side

log = logging.getLogger(__name__)

__all__ = ["SegmentationConfig", "Segmentation", "segment_links", "adaptive_hypotheses"]


@dataclass(frozen=True)
class SegmentationConfig:
    """Sequential-RANSAC settings; lengths are fractions of the scene size (see tolerances)."""

    inlier_threshold: float = tol.INLIER_THRESHOLD
    """Inlier distance in configuration B, as a fraction of B's scene size."""
    adaptive_threshold_factor: float | None = tol.ADAPTIVE_THRESHOLD_FACTOR
    """Refined inlier distance = this x median inlier residual (capped by inlier_threshold);
    None keeps the fixed inlier_threshold."""
    min_link_points: int = tol.MIN_LINK_POINTS
    """A link has at least this many matches."""
    min_link_fraction: float = tol.MIN_LINK_FRACTION
    """A link has at least this fraction of all matches."""
    confidence: float = tol.RANSAC_CONFIDENCE
    """Probability that each round samples at least one all-inlier triplet of its best link."""
    max_hypotheses: int = tol.MAX_HYPOTHESES
    """Cap on hypotheses per round (the last, empty round runs to it)."""
    min_hypotheses: int = tol.MIN_HYPOTHESES
    """Floor on hypotheses per round."""
    min_triplet_spread: float = tol.MIN_TRIPLET_SPREAD
    """Triplets with area below (this x scene size)^2 are skipped as degenerate."""
    score_subset: int = tol.SCORE_SUBSET
    """Hypotheses are scored on at most this many randomly chosen matches."""
    batch_size: int = 256
    """Hypotheses fitted and scored together."""
    refine_iterations: int = 10
    """Refit-on-inliers rounds per link (stops early when the inlier set is stable)."""
    shared_scale: bool = True
    """All links share one A->B scale (true for two SfM models of one object)."""
    max_links: int = 32
    """Stop after this many links."""
    min_links: int = 2
    """Fewer links raise SingleBodyError / NoMotionError (set 1 to accept a single rigid body)."""
    restarts: int = 8
    """Independent sequential-RANSAC runs (seeded from ``seed``); the one kept explains the matches
    best (see :func:`select_run`). A single run's links hinge on which borderline matches its draws
    admit: on the pliers, one match of 69 on the moving half moved the axis by 1.8 deg."""
    selection_factor: float = 2.0
    """The runs are compared by their residuals truncated at this x the runs' median member
    residual (tight: among equally large link sets, the one that fits its matches best)."""
    covariances: bool = True
    """Refit the links' motions with the matches' triangulation covariances when they are known
    (:func:`artrecon.link_motions.robust_refit`, :mod:`artrecon.uncertainty`); False: isotropic
    (every direction of every match alike)."""


@dataclass
class Segmentation:
    """Result of `segment_links`.

    Attributes
    ----------
    labels : (n,) int
        Link index of each match, -1 for outliers. Links are sorted by size: link 0 is the largest.
    transforms : list of Similarity
        Per link, maps configuration A to configuration B (p_b ~ T.apply(p_a)).
    scale : float
        Common A->B scale (every transform has it when `shared_scale`).
    thresholds : list of float
        Per link, the final inlier distance (B units).
    scene_size_a, scene_size_b : float
        Robust scene sizes of points_a and points_b (tolerances.scene_size).
    hypotheses : list of int
        Hypotheses drawn in each RANSAC round (the last round is the one that found no link).
    rms : list of float
        Per link, RMS residual of its members (B units).
    weights : (n,) float or None
        Weight of each match in its link's fit (robust refit, 0-1]; None: every member counts
        fully (least squares).
    precisions : (n, 3, 3) float or None
        Weight matrix of each match in its link's fit when the fit knew the matches' point
        covariances (:func:`artrecon.uncertainty.robust_gls_transforms`: its weight times the
        inverse covariance of its residual, B units); None: the fit was isotropic (``weights``).
    surface_information, surface_gradient : (n_links, 6, 6), (n_links, 6) float or None
        What each link's dense surface says of its motion (:func:`artrecon.surface_fit.
        surface_refit`: the surface term's Gauss-Newton matrix and gradient at the motion); None
        or zero: the motion is the matches' alone.
    """

    labels: np.ndarray
    transforms: list[Similarity]
    scale: float
    thresholds: list[float] = field(default_factory=list)
    scene_size_a: float = 1.0
    scene_size_b: float = 1.0
    hypotheses: list[int] = field(default_factory=list)
    rms: list[float] = field(default_factory=list)
    weights: np.ndarray | None = None
    precisions: np.ndarray | None = None
    surface_information: np.ndarray | None = None
    surface_gradient: np.ndarray | None = None

    @property
    def n_links(self) -> int:
        return len(self.transforms)

    @property
    def sizes(self) -> np.ndarray:
        """(n_links,) int, matches per link."""
        return np.bincount(self.labels[self.labels >= 0], minlength=self.n_links)

    def members(self, link: int) -> np.ndarray:
        """(m,) int, indices of the matches of one link."""
        return np.flatnonzero(self.labels == link)

    @property
    def outliers(self) -> np.ndarray:
        return np.flatnonzero(self.labels < 0)


def adaptive_hypotheses(inlier_ratio: float, confidence: float, sample_size: int = 3) -> float:
    """Hypotheses needed to draw one all-inlier sample with the given confidence.

    N = log(1 - confidence) / log(1 - w^k); inf when w = 0, 1 when w = 1.
    """
    w = float(np.clip(inlier_ratio, 0.0, 1.0))
    p_good = w**sample_size
    if p_good <= 0.0:
        return math.inf
    if p_good >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log1p(-p_good)


def _residuals_sq(rot, trans, scales, pa, pb) -> np.ndarray:
    """(m, n) squared residuals ||s R a + t - b||^2 of m hypotheses on n matches."""
    sr_t = scales[:, None, None] * np.transpose(rot, (0, 2, 1))
    diff = np.matmul(pa[None], sr_t)
    diff += (trans[:, None, :] - pb[None])
    return np.einsum("mnk,mnk->mn", diff, diff)


def _score(rot, trans, scales, pa, pb, thr2) -> tuple[np.ndarray, np.ndarray]:
    """MSAC scores (sum of max(thr^2 - r^2, 0), higher is better) and inlier counts."""
    m, n = len(rot), len(pa)
    chunk = max(1, tol.SCORE_CHUNK // max(n, 1))
    scores = np.empty(m)
    counts = np.empty(m, dtype=np.int64)
    for i in range(0, m, chunk):
        r2 = _residuals_sq(rot[i : i + chunk], trans[i : i + chunk], scales[i : i + chunk], pa, pb)
        scores[i : i + chunk] = np.maximum(thr2 - r2, 0.0).sum(axis=1)
        counts[i : i + chunk] = (r2 < thr2).sum(axis=1)
    return scores, counts


def min_link_size(config: SegmentationConfig, n: int) -> int:
    """Fewest matches a link may have among ``n``: SegmentationConfig.min_link_points, or
    min_link_fraction of them, and at least the 3 a transform needs."""
    return max(config.min_link_points, math.ceil(config.min_link_fraction * n), 3)


def _ransac_round(pa, pb, thr, size_a, scale, min_size, rng, cfg):
    """Best hypothesis on the remaining matches; returns (Similarity | None, hypotheses drawn)."""
    m = len(pa)
    if m > cfg.score_subset:
        sub = rng.choice(m, size=cfg.score_subset, replace=False)
        sa, sb = pa[sub], pb[sub]
    else:
        sa, sb = pa, pb
    n_probe = min(len(sa), tol.PROBE_SIZE)
    probe_a, probe_b = sa[:n_probe], sb[:n_probe]  # sa is in random order when subsampled
    if len(sa) == m:
        pick = rng.choice(m, size=n_probe, replace=False)
        probe_a, probe_b = pa[pick], pb[pick]
    w_min = min_size / m
    thr2 = thr * thr
    min_area2 = (cfg.min_triplet_spread * size_a) ** 4  # compare squared doubled areas
    best_score = -1.0
    best_count = 0
    best = None
    needed = cfg.max_hypotheses
    drawn = 0
    while drawn < needed:
        b = min(cfg.batch_size, needed - drawn)
        idx = rng.integers(0, m, size=(b, 3))
        tri_a = pa[idx]
        cross = np.cross(tri_a[:, 1] - tri_a[:, 0], tri_a[:, 2] - tri_a[:, 0])
        valid = np.einsum("ij,ij->i", cross, cross) > 4.0 * min_area2
        drawn += b
        if not np.any(valid):
            continue
        idx = idx[valid]
        rot, trans, scales = batch_similarity_transforms(pa[idx], pb[idx], scale)
        ok = np.isfinite(scales) & (scales > 0)
        if not np.any(ok):
            continue
        rot, trans, scales = rot[ok], trans[ok], scales[ok]
        if len(sa) > 2 * len(probe_a):
            # Preliminary test on a few matches: a hypothesis that cannot beat half the inlier
            # ratio of the best so far (or of the smallest acceptable link) is not fully scored.
            _, probe_counts = _score(rot, trans, scales, probe_a, probe_b, thr2)
            keep = probe_counts >= 0.5 * max(best_count / len(sa), w_min) * len(probe_a)
            if not np.any(keep):
                continue
            rot, trans, scales = rot[keep], trans[keep], scales[keep]
        scores, counts = _score(rot, trans, scales, sa, sb, thr2)
        j = int(np.argmax(scores))
        if scores[j] > best_score:
            best_score = float(scores[j])
            best_count = int(counts[j])
            best = Similarity(rot[j], trans[j], float(scales[j]))
            w = best_count / len(sa)
            needed = int(
                np.clip(
                    math.ceil(min(adaptive_hypotheses(w, cfg.confidence), 1e12)),
                    cfg.min_hypotheses,
                    cfg.max_hypotheses,
                )
            )
    return best, drawn


def _fit(pa, pb, scale):
    if scale is None:
        return similarity_transform(pa, pb)
    return rigid_transform(pa, pb, scale=scale)


def _link_threshold(res, mask, thr, floor, cfg) -> float:
    if cfg.adaptive_threshold_factor is None or not np.any(mask):
        return thr
    return float(min(thr, max(cfg.adaptive_threshold_factor * np.median(res[mask]), floor)))


def _refine(pa, pb, transform, thr, floor, scale, cfg):
    """Refit on all inliers until the inlier set is stable; returns (transform, mask, threshold)."""
    res = np.linalg.norm(transform.apply(pa) - pb, axis=1)
    mask = res < thr
    t_k = thr
    for _ in range(cfg.refine_iterations):
        if mask.sum() < 3:
            break
        try:
            transform = _fit(pa[mask], pb[mask], scale)
        except DegenerateError:
            break
        res = np.linalg.norm(transform.apply(pa) - pb, axis=1)
        t_k = _link_threshold(res, mask, thr, floor, cfg)
        new = res < t_k
        if np.array_equal(new, mask):
            break
        mask = new
    return transform, mask, t_k


def _validate(points_a, points_b):
    pa = np.asarray(points_a, dtype=float)
    pb = np.asarray(points_b, dtype=float)
    if pa.ndim != 2 or pa.shape[1] != 3:
        raise ValueError(f"points_a must have shape (n, 3), got {pa.shape}")
    if pb.shape != pa.shape:
        raise ValueError(f"points_b must have the shape of points_a {pa.shape}, got {pb.shape}")
    if not (np.all(np.isfinite(pa)) and np.all(np.isfinite(pb))):
        raise ValueError("points_a and points_b must be finite (found NaN or inf)")
    n = len(pa)
    if n < 3:
        raise DegenerateError(
            f"segment_links got {n} matches; at least 3 are needed to fit one transform (and many "
            "more to find links): match more features between the two configurations."
        )
    for name, p in (("points_a", pa), ("points_b", pb)):
        sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
        if sv[0] == 0 or sv[1] <= tol.COLLINEAR_RATIO * sv[0]:
            raise DegenerateError(
                f"segment_links: all {n} matched points of {name} are collinear (or coincide); "
                "rigid motions cannot be told apart. Match features over the whole object."
            )
    return pa, pb


def segment_links(
    points_a: np.ndarray,
    points_b: np.ndarray,
    config: SegmentationConfig = SegmentationConfig(),  # noqa: B008 (frozen, immutable)
    seed: int = 0,
) -> Segmentation:
    """Segment 3D-3D matches into rigid links, each with its similarity transform A -> B.

    Parameters
    ----------
    points_a : (n, 3) float
        Matched points in configuration A (its SfM model frame).
    points_b : (n, 3) float
        The same features in configuration B (its own SfM frame and scale).
    config : SegmentationConfig
    seed : int
        Seed of the random triplet sampling; same inputs and seed give the same result.

    Returns
    -------
    Segmentation
        Links sorted by size (link 0 largest); every match is a link member or -1.

    Raises
    ------
    DegenerateError
        Fewer than 3 matches, or collinear points.
    NoMotionError
        One link explains everything and it is the identity: nothing moved.
    SingleBodyError
        Fewer than `config.min_links` links: the object moved as one rigid body.
    """
    pa, pb = _validate(points_a, points_b)
    n = len(pa)
    size_a = tol.scene_size(pa)
    size_b = tol.scene_size(pb)
    if size_a <= 0 or size_b <= 0:
        raise DegenerateError(
            "segment_links: more than half of the matched points coincide (scene size 0); "
            "check the 3D points of the matches."
        )
    thr = config.inlier_threshold * size_b
    floor = tol.ADAPTIVE_THRESHOLD_FLOOR * size_b
    min_size = min_link_size(config, n)

    def run(r: int):
        return _sequential_ransac(pa, pb, thr, floor, size_a, min_size,
                                  np.random.default_rng(seed if r == 0 else [seed, r]), config)

    # the runs are independent (each its own draws): half of them in a thread beside this one
    # (their batches of hypotheses are numpy products that release the GIL), in their order
    restarts = range(max(1, config.restarts))
    even, odd = side_by_side(lambda: [run(r) for r in restarts[0::2]],
                             lambda: [run(r) for r in restarts[1::2]])
    runs = [even[r // 2] if r % 2 == 0 else odd[r // 2] for r in restarts]
    labels, transforms, thresholds, rms, hypotheses = runs[select_run(runs, pa, pb, floor,
                                                                      config)]
    seg = Segmentation(
        labels=labels,
        transforms=transforms,
        scale=float(transforms[0].scale) if transforms else float("nan"),
        thresholds=thresholds,
        scene_size_a=size_a,
        scene_size_b=size_b,
        hypotheses=hypotheses,
        rms=rms,
    )
    _check_articulated(seg, pa, n, min_size, config)
    log.info(
        "segment_links: %d matches -> %d links %s, %d outliers, %d hypotheses",
        n, seg.n_links, seg.sizes.tolist(), len(seg.outliers), sum(hypotheses),
    )
    return seg


def _fit_links(pa, pb, links, config):
    if config.shared_scale:
        return shared_scale_transforms([(pa[i], pb[i]) for i in links])
    return [similarity_transform(pa[i], pb[i]) for i in links]


def _reassign(pa, pb, links, thr, floor, min_size, config):
    """Give every match to the link explaining it best; refit; dissolve too-small links."""
    n = len(pa)
    labels = np.full(n, -1, dtype=np.int64)
    for _ in range(3):
        links = [i for i in links if len(i) >= min_size]
        if not links:
            return labels, [], [], []
        try:
            transforms = _fit_links(pa, pb, links, config)
        except DegenerateError as exc:
            log.warning("segment_links: dropping degenerate links while refitting: %s", exc)
            links = [i for i in links if _spans_plane(pa[i])]
            continue
        res = np.stack([np.linalg.norm(t.apply(pa) - pb, axis=1) for t in transforms])
        thresholds = np.array(
            [
                _link_threshold(res[k], np.isin(np.arange(n), links[k]), thr, floor, config)
                for k in range(len(links))
            ]
        )
        ok = res < thresholds[:, None]
        new_labels = np.where(ok.any(axis=0), np.argmin(np.where(ok, res, np.inf), axis=0), -1)
        order = np.argsort(-np.bincount(new_labels[new_labels >= 0], minlength=len(links)),
                           kind="stable")
        new_links = [np.flatnonzero(new_labels == k) for k in order]
        if len(new_links) == len(links) and all(
            np.array_equal(a, b) for a, b in zip(new_links, links, strict=True)
        ):
            break
        links = new_links
    links = [i for i in links if len(i) >= min_size]
    if not links:
        return labels, [], [], []
    transforms = _fit_links(pa, pb, links, config)
    thresholds, rms = [], []
    for k, (idx, t) in enumerate(zip(links, transforms, strict=True)):
        labels[idx] = k
        r = np.linalg.norm(t.apply(pa[idx]) - pb[idx], axis=1)
        rms.append(float(np.sqrt(np.mean(r**2))))
        res_all = np.linalg.norm(t.apply(pa) - pb, axis=1)
        thresholds.append(_link_threshold(res_all, labels == k, thr, floor, config))
    return labels, transforms, thresholds, rms


def _sequential_ransac(pa, pb, thr, floor, size_a, min_size, rng, config):
    """One run: links found one after another, then every match given to its best link.
    Returns (labels, transforms, thresholds, rms, hypotheses)."""
    n = len(pa)
    links: list[np.ndarray] = []
    scale: float | None = None
    hypotheses: list[int] = []
    remaining = np.arange(n)
    while len(remaining) >= min_size and len(links) < config.max_links:
        best, drawn = _ransac_round(
            pa[remaining], pb[remaining], thr, size_a, scale, min_size, rng, config
        )
        hypotheses.append(drawn)
        if best is None:
            break
        transform, mask, _ = _refine(
            pa[remaining], pb[remaining], best, thr, floor, scale, config
        )
        if mask.sum() < min_size:
            break
        if scale is None and config.shared_scale:
            scale = transform.scale
        links.append(remaining[mask])
        log.debug("link %d: %d matches, %d hypotheses", len(links) - 1, mask.sum(), drawn)
        remaining = remaining[~mask]
    return (*_reassign(pa, pb, links, thr, floor, min_size, config), hypotheses)


def select_run(runs, pa, pb, floor: float, config: SegmentationConfig) -> int:
    """Index of the run that explains the matches best.

    Among the runs that found the most frequent number of links (ties: fewer links; a run that
    split off a sliver of noise, or missed a link, is the odd one out), the one with the least
    truncated squared residual sum(min(r_i, tau)^2), r_i the match's residual under its nearest
    link's transform and tau = ``selection_factor`` x the median member residual over those runs:
    an MSAC score at the matches' own noise level, so that the run whose links fit their members
    tightly wins over one that admitted borderline matches. Ties: the earliest run.
    """
    counts = np.array([len(r[1]) for r in runs])
    values, freq = np.unique(counts, return_counts=True)
    modal = values[np.lexsort((values, -freq))[0]]
    cands = [i for i in range(len(runs)) if counts[i] == modal]
    if len(cands) == 1 or modal == 0:
        return cands[0]
    res = {}
    for i in cands:
        res[i] = np.min(np.stack([np.linalg.norm(t.apply(pa) - pb, axis=1)
                                  for t in runs[i][1]]), axis=0)
    members = [np.median(res[i][runs[i][0] >= 0]) for i in cands if np.any(runs[i][0] >= 0)]
    tau = max(config.selection_factor * float(np.median(members)), floor) if members else floor
    costs = [float(np.sum(np.minimum(res[i], tau) ** 2)) for i in cands]
    best = cands[int(np.argmin(costs))]
    log.debug("segment_links: %d runs, %d with %d links; costs %s (tau %.3g); kept run %d",
              len(runs), len(cands), modal, np.round(costs, 6).tolist(), tau, best)
    return best


def _spans_plane(p: np.ndarray) -> bool:
    if len(p) < 3:
        return False
    sv = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[1] > tol.COLLINEAR_RATIO * sv[0])


def _check_articulated(seg: Segmentation, pa, n, min_size, config) -> None:
    if seg.n_links >= config.min_links:
        return
    if seg.n_links == 0:
        raise DegenerateError(
            f"segment_links: no similarity transform explains {min_size} of the {n} matches "
            f"within {config.inlier_threshold:g} x scene size: the matches are mostly wrong or "
            "very noisy. Check the matching, or raise SegmentationConfig.inlier_threshold."
        )
    t = seg.transforms[0]
    moved = np.linalg.norm(t.apply(pa) - pa, axis=1)
    if (
        rotation_angle(t.rotation) < tol.REVOLUTE_MIN_ANGLE
        and np.median(moved) < tol.NO_MOTION_DISPLACEMENT * seg.scene_size_a
    ):
        raise NoMotionError(
            f"segment_links: all {seg.sizes[0]} inlier matches (of {n}) map to themselves: the "
            "two configurations are identical. Move a joint of the object between the captures."
        )
    raise SingleBodyError(
        f"segment_links: found {seg.n_links} rigid link(s) ({seg.sizes.tolist()} matches, "
        f"{len(seg.outliers)} outliers of {n}); need {config.min_links}. The object moved as one "
        f"rigid body, or its moving part has fewer than {min_size} good matches (the minimum link "
        "size). Move a joint between the captures, photograph the moving part more, or lower "
        "SegmentationConfig.min_link_fraction / min_link_points."
    )
