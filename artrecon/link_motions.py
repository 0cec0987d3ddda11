"""The links' motions, A -> B, after segmentation: made as exact as the evidence allows.

Sequential RANSAC (:func:`artrecon.segment.segment_links`) gives each link a motion fitted to
its inlier matches. :func:`artrecon.articulation.articulate` then runs these steps, in order:

- :func:`merge_equivalent_links`: links that move alike are one rigid body split by RANSAC;
- :func:`anchor_base`: the base is the link the background moves with (:func:`static_link`), and
  its motion is fitted to the background matches too (:func:`anchor_to_background`: a thin
  base's roll is pinned by the table and room);
- :func:`add_guided_matches`: SfM points the matching left out, matched again under each link's
  motion (:func:`artrecon.features.guided_matches`);
- :func:`robust_refit`: every link's motion refitted as the maximum-likelihood fit under
  Cauchy-distributed match errors, weighing each match by its triangulation covariances when
  they are known (:func:`fit_covariances` gathers them row for row).

Plain data in and out: matches as (n, 3) arrays, a :class:`artrecon.segment.Segmentation`.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from artrecon.features import GuidedConfig, PointDescriptors, guided_matches
from artrecon.geometry import rotation_angle
from artrecon.procrustes import (
    rigid_transform,
    robust_shared_scale_transforms,
    shared_scale_transforms,
)
from artrecon.segment import Segmentation
from artrecon.uncertainty import MatchCovariances, robust_gls_transforms

log = logging.getLogger(__name__)

#: Two links whose relative motion moves the second one's matches by less than this fraction
#: of the scene size, with a relative rotation under MERGE_MAX_ROTATION, are one rigid body
#: split by sequential RANSAC (seen: a 0.46 mm "drawer" of 96 matches beside a 10 cm pull). A
#: joint worth modelling moves by centimetres or degrees, far above 0.5% / 1 degree.
MERGE_MAX_DISPLACEMENT = 0.005
MERGE_MAX_ROTATION = np.deg2rad(1.0)
#: ... or whose relative motion moves the second one's matches (RMS) by less than this many times
#: the two links' match residual (RMS, the larger): a motion the noise could make is no joint
#: (artrecon.confidence refuses such a joint with the same ratio, MIN_MOTION_SNR; seen: a
#: barrett_hand run split off a "link" moving 1.5 x the noise, 0.18 deg, beside the two fingers).
MERGE_MIN_MOTION_SNR = 3.0
#: Fewest background matches needed to pick the root from them (else: the largest link).
MIN_BACKGROUND_MATCHES = 20
#: The base's median background residual must be below this fraction of every other link's.
#: Background points (walls) are triangulated less precisely than the object, so no absolute
#: inlier distance fits them; but a moving link displaces them by far more than their noise.
BACKGROUND_MARGIN = 0.5
#: Most refits of the base's transform with the background matches (see anchor_to_background;
#: it stops when they no longer change).
ANCHOR_ITERATIONS = 10
#: The anchored transform must still fit the base's own matches: their RMS residual may grow to
#: at most this factor of the base-only fit's, else the base moved against the room and the
#: background is left out (measured: 0.9-1.1 on the bundled scenes, whose base stays put).
ANCHOR_MAX_RMS_GROWTH = 1.5


def merge_equivalent_links(points_a: np.ndarray, points_b: np.ndarray,
                           seg: Segmentation) -> Segmentation:
    """Merge links that move the same way (one rigid body split by sequential RANSAC).

    Sequential RANSAC with an inlier distance refined down to the noise level can cut one rigid
    body into several links with the same transform (seen on metric, low-noise matches). Link j
    joins link i when i's transform explains j's matches about as well as j's own (median
    residual below the larger of the two links' inlier thresholds), or when j hardly moves
    relative to i (MERGE_MAX_DISPLACEMENT, MERGE_MAX_ROTATION), or moves by less than
    MERGE_MIN_MOTION_SNR x the links' residual noise. Links are refitted (rigid, the common scale
    kept) after each merge; link order stays by size.
    """
    size_a = seg.scene_size_a
    labels = np.asarray(seg.labels).copy()
    transforms = list(seg.transforms)
    thresholds = list(seg.thresholds) if seg.thresholds else [np.inf] * len(transforms)
    merged = True
    while merged and len(transforms) > 1:
        merged = False
        for i in range(len(transforms)):
            for j in range(i + 1, len(transforms)):
                mj = labels == j
                res = np.linalg.norm(transforms[i].apply(points_a[mj]) - points_b[mj], axis=1)
                rel = transforms[i].inverse() @ transforms[j]
                moved = np.median(np.linalg.norm(rel.apply(points_a[mj]) - points_a[mj], axis=1))
                still = (moved < MERGE_MAX_DISPLACEMENT * size_a
                         and rotation_angle(rel.rotation) < MERGE_MAX_ROTATION)
                if not still:
                    # motion (RMS, in B units like the residuals) against the links' noise
                    mi = labels == i
                    disp = motion_rms(transforms[i], points_a[mj],
                                      transforms[j].apply(points_a[mj]))
                    noise = max(motion_rms(transforms[i], points_a[mi], points_b[mi]),
                                motion_rms(transforms[j], points_a[mj], points_b[mj]))
                    still = bool(disp < MERGE_MIN_MOTION_SNR * noise)
                if still or np.median(res) < max(thresholds[i], thresholds[j]):
                    labels[mj] = i
                    labels[labels > j] -= 1
                    mi = labels == i
                    transforms[i] = rigid_transform(points_a[mi], points_b[mi], scale=seg.scale)
                    del transforms[j], thresholds[j]
                    merged = True
                    break
            if merged:
                break
    if len(transforms) == seg.n_links:
        return seg
    sizes = np.bincount(labels[labels >= 0], minlength=len(transforms))
    order = np.argsort(-sizes, kind="stable")
    remap = np.full(len(order), -1)
    remap[order] = np.arange(len(order))
    labels = np.where(labels >= 0, remap[np.maximum(labels, 0)], -1)
    transforms = [transforms[k] for k in order]
    rms = []
    for k, T in enumerate(transforms):
        m = labels == k
        rms.append(float(np.sqrt(np.mean(np.sum((T.apply(points_a[m]) - points_b[m]) ** 2, 1)))))
    log.info("merged links moving alike: %d -> %d links", seg.n_links, len(transforms))
    return Segmentation(labels=labels, transforms=transforms, scale=seg.scale,
                        thresholds=[thresholds[k] for k in order],
                        scene_size_a=seg.scene_size_a, scene_size_b=seg.scene_size_b,
                        hypotheses=list(seg.hypotheses), rms=rms)


def motion_rms(T, pa: np.ndarray, pb: np.ndarray) -> float:
    """RMS distance of ``T.apply(pa)`` to ``pb`` (0 for no pairs)."""
    if len(pa) == 0:
        return 0.0
    return float(np.sqrt(np.mean(np.sum((T.apply(pa) - pb) ** 2, axis=1))))


def static_link(segmentation: Segmentation, background_a: np.ndarray,
                background_b: np.ndarray) -> int | None:
    """The link that moves with the static background (the base), or None if unclear.

    Parameters
    ----------
    segmentation : Segmentation
    background_a, background_b : (m, 3) float
        Matched background points (table, room) of configuration A and B.

    Returns
    -------
    int or None
        Link whose A->B transform gives the background matches the smallest median residual;
        None with fewer than MIN_BACKGROUND_MATCHES matches or when that median is not below
        BACKGROUND_MARGIN x every other link's.
    """
    if len(background_a) < MIN_BACKGROUND_MATCHES:
        return None
    medians = np.array([np.median(np.linalg.norm(T.apply(background_a) - background_b, axis=1))
                        for T in segmentation.transforms])
    log.info("background matches (%d): median residual per link %s", len(background_a),
             np.array2string(medians, precision=4))
    order = np.argsort(medians)
    best = int(order[0])
    if len(order) > 1 and medians[best] >= BACKGROUND_MARGIN * medians[order[1]]:
        return None
    return best


def anchor_to_background(points_a: np.ndarray, points_b: np.ndarray, seg: Segmentation,
                         root: int, background_a: np.ndarray, background_b: np.ndarray
                         ) -> tuple[Segmentation, tuple[np.ndarray, np.ndarray] | None]:
    """Fit the base's motion to its matches and the background matches it carries along.

    The base (the link that moves with the room, :func:`static_link`) and the room are one rigid
    body across the two captures: the background matches it explains (within its inlier
    distance) join its matches, and every link is refitted with the common scale. The base of a
    pliers or scissors is long and thin, so its own matches leave its roll about its length
    loosely held; the table and room around it pin its motion, and with it the frame the joints
    are measured in (the relative motion parent^-1 child). Starting from the base's own fit, each
    round keeps the background matches within the larger of the base's inlier distance and their
    median residual and refits (up to :data:`ANCHOR_ITERATIONS` rounds); the last fit takes those
    within the inlier distance.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        The segmented matches.
    seg : Segmentation
    root : int
        The base link.
    background_a, background_b : (m, 3) float
        Matched background points of A and B.

    Returns
    -------
    seg : Segmentation
        With refitted transforms, scale and RMS residuals; ``seg`` itself when fewer than
        :data:`MIN_BACKGROUND_MATCHES` background matches fit the base, or when the refit no
        longer fits the base's own matches (RMS above :data:`ANCHOR_MAX_RMS_GROWTH` x): the base
        then moved against the room.
    anchor : (background_a, background_b) or None
        The background matches that joined the base (for the confidence's bootstrap).
    """
    labels = np.asarray(seg.labels)
    groups = [(points_a[labels == k], points_b[labels == k]) for k in range(seg.n_links)]
    own_a, own_b = groups[root]
    rms_own = motion_rms(seg.transforms[root], own_a, own_b)
    thr = seg.thresholds[root] if seg.thresholds else 3.0 * rms_own

    def fit(used):
        anchored = list(groups)
        anchored[root] = (np.vstack([own_a, background_a[used]]),
                          np.vstack([own_b, background_b[used]]))
        return shared_scale_transforms(anchored)

    def residuals(transforms):
        return np.linalg.norm(transforms[root].apply(background_a) - background_b, axis=1)

    # From the base's own fit, which may be off by a degree far from its matches, towards the
    # room's motion: each round keeps the background matches within the larger of the base's
    # inlier distance and their median residual, and refits.
    transforms, used = list(seg.transforms), None
    for _ in range(ANCHOR_ITERATIONS):
        res = residuals(transforms)
        fits = res < max(thr, float(np.median(res)))
        if used is not None and np.array_equal(fits, used):
            break
        used = fits
        transforms = fit(used)
    used = residuals(transforms) < thr
    if used.sum() < MIN_BACKGROUND_MATCHES:
        log.info("base link %d: %d background matches within its inlier distance (need %d); "
                 "its motion is fitted to its own matches", root, used.sum(),
                 MIN_BACKGROUND_MATCHES)
        return seg, None
    transforms = fit(used)
    rms_anchored = motion_rms(transforms[root], own_a, own_b)
    if rms_anchored > ANCHOR_MAX_RMS_GROWTH * rms_own:
        log.warning("base link %d: fitted with the background its matches' residual grows from "
                    "%.3g to %.3g RMS; the base moved against the room, its motion is fitted to "
                    "its own matches", root, rms_own, rms_anchored)
        return seg, None
    log.info("base link %d anchored to %d background matches (its matches' RMS %.3g -> %.3g)",
             root, used.sum(), rms_own, rms_anchored)
    rms = [motion_rms(T, a, b) for T, (a, b) in zip(transforms, groups, strict=True)]
    return replace(seg, transforms=transforms, scale=float(transforms[0].scale), rms=rms), \
        (background_a[used], background_b[used])


def anchor_base(points_a: np.ndarray, points_b: np.ndarray, seg: Segmentation,
                background_a: np.ndarray, background_b: np.ndarray
                ) -> tuple[Segmentation, int | None, dict | None]:
    """The base (:func:`static_link`) and the segmentation with the base's motion fitted to the
    background too (:func:`anchor_to_background`), as the pipeline runs them after segmenting.

    Returns
    -------
    seg : Segmentation
    root : int or None
        The base, None when the background does not show it.
    anchors : dict or None
        ``{root: (background_a, background_b)}`` for :func:`artrecon.confidence.assess_joints`,
        None when the base was not anchored.
    """
    root = static_link(seg, background_a, background_b)
    if root is None:
        return seg, None, None
    seg, anchor = anchor_to_background(points_a, points_b, seg, root, background_a, background_b)
    return seg, root, None if anchor is None else {root: anchor}


def add_guided_matches(points_a: np.ndarray, points_b: np.ndarray, seg: Segmentation,
                       candidates: tuple[PointDescriptors, PointDescriptors],
                       anchors: dict | None, config: GuidedConfig | None = None
                       ) -> tuple[np.ndarray, np.ndarray, Segmentation, np.ndarray]:
    """The segmented matches with the guided ones (:func:`artrecon.features.guided_matches`)
    added to their links, and every link's motion refitted to them (one common scale; the base
    with the background matches it was anchored to).

    Each round matches the candidates afresh with the motions of the previous one, so the
    guided set is never counted twice.

    Returns
    -------
    points_a, points_b : (n + m, 3) float
        The matches, the guided ones appended.
    seg : Segmentation
        Labels for all of them (the guided ones carry their link), refitted transforms, RMS.
    ids : (m, 2) int
        The SfM point ids (A, B) of the appended matches.
    """
    config = config or GuidedConfig()
    cand_a, cand_b = candidates
    base_a, base_b, base_labels = points_a, points_b, np.asarray(seg.labels)
    ids = np.zeros((0, 2), np.int64)
    for _ in range(config.rounds):
        ia, ib, link = guided_matches(seg.transforms, seg.thresholds or [0.0] * seg.n_links,
                                      cand_a, cand_b, config)
        pa = np.vstack([base_a, cand_a.xyz[ia]])
        pb = np.vstack([base_b, cand_b.xyz[ib]])
        labels = np.concatenate([base_labels, link])
        groups = []
        for k in range(seg.n_links):
            ga, gb = pa[labels == k], pb[labels == k]
            if anchors and k in anchors:
                ga, gb = np.vstack([ga, anchors[k][0]]), np.vstack([gb, anchors[k][1]])
            groups.append((ga, gb))
        transforms = shared_scale_transforms(groups)
        rms = [motion_rms(T, pa[labels == k], pb[labels == k]) for k, T in enumerate(transforms)]
        seg = replace(seg, labels=labels, transforms=transforms, scale=float(transforms[0].scale),
                      rms=rms)
        points_a, points_b = pa, pb
        ids = np.c_[cand_a.ids[ia], cand_b.ids[ib]]
    log.info("guided matching: %d matches added (%s per link)", len(ids),
             np.bincount(seg.labels[len(base_labels):], minlength=seg.n_links).tolist())
    return points_a, points_b, seg, ids


def robust_refit(points_a: np.ndarray, points_b: np.ndarray, seg: Segmentation,
                 anchors: dict | None, covariances: tuple | None = None
                 ) -> tuple[Segmentation, dict | None]:
    """Every link's motion refitted to its matches (the base's with the background matches it
    was anchored to), robust to the few gross errors among them
    (:func:`artrecon.procrustes.robust_shared_scale_transforms`, one common scale), and, when
    the matches' triangulation covariances are given, weighing each match's directions by how
    precisely its two points are known (:func:`artrecon.uncertainty.robust_gls_transforms`).

    Least squares follows every match it is given. Near a hinge the two links' features crowd,
    and a handful of matches a few noise levels off (seen: 4 of the 152 of pliers_panda's moving
    half, within 13 mm of the pin, 1-2.6 mm off) tilt the small link's rotation and the axis with
    it (2.1 degrees there). The maximum-likelihood fit under heavy-tailed (Cauchy) noise, each
    population's noise scale estimated with it (the link's matches; the background matches,
    noisier), gives such matches little say and the others most of it.

    Triangulation pins a point across its viewing rays several times better than along them;
    isotropic weights let a thin link take its matches' depth errors for a rotation about its
    length (scraper_truck's boom: 0.38 degrees of roll from 115 matches 3 cm across, which tilted
    both hinges' axes by 0.7-0.8 degrees; 0.12 with the covariances).

    Parameters
    ----------
    points_a, points_b : (n, 3) float
    seg : Segmentation
    anchors : dict or None
        ``{link: (background_a, background_b)}`` (:func:`anchor_to_background`).
    covariances : (cov_a (n, 3, 3), cov_b (n, 3, 3), anchor_covariances) or None
        The matches' point covariances (:func:`artrecon.uncertainty.point_covariances`) and
        ``{link: (cov_background_a, cov_background_b)}`` for the anchors; None: isotropic.

    Returns
    -------
    seg : Segmentation
        Refitted transforms, scale and RMS residuals; ``weights`` per match (and
        ``precisions``, the weight matrices, with covariances).
    anchors : dict or None
        ``{link: (background_a, background_b, weights[, weight_matrices])}``.
    """
    labels = np.asarray(seg.labels)
    groups, pops, sizes, covs = [], [], [], []
    for k in range(seg.n_links):
        mk = labels == k
        ga, gb = points_a[mk], points_b[mk]
        sizes.append(len(ga))
        pk = np.zeros(len(ga), np.int64)
        if covariances is not None:
            ca, cb = covariances[0][mk], covariances[1][mk]
        if anchors and k in anchors:
            xa, xb = anchors[k][:2]
            ga, gb, pk = np.vstack([ga, xa]), np.vstack([gb, xb]), np.r_[pk, np.ones(len(xa), int)]
            if covariances is not None:
                ca = np.concatenate([ca, covariances[2][k][0]])
                cb = np.concatenate([cb, covariances[2][k][1]])
        groups.append((ga, gb))
        pops.append(pk)
        if covariances is not None:
            covs.append((ca, cb))
    mats = None
    if covariances is not None:
        transforms, weights, mats = robust_gls_transforms(groups, covs, pops)
    else:
        transforms, weights = robust_shared_scale_transforms(groups, pops)
    w = np.ones(len(labels))
    precisions = None if mats is None else np.zeros((len(labels), 3, 3))
    for k, (wk, nk) in enumerate(zip(weights, sizes, strict=True)):
        w[labels == k] = wk[:nk]
        if mats is not None:
            precisions[labels == k] = mats[k][:nk]
    if anchors:
        anchors = {k: (*anchors[k][:2], weights[k][sizes[k]:])
                   + (() if mats is None else (mats[k][sizes[k]:],)) for k in anchors}
    for k, (T0, T1) in enumerate(zip(seg.transforms, transforms, strict=True)):
        log.info("robust refit%s: link %d turned %.3g deg from least squares; %d of its %d "
                 "matches weigh under a tenth of their median",
                 " (triangulation covariances)" if mats is not None else "", k,
                 np.degrees(rotation_angle(T0.rotation.T @ T1.rotation)),
                 int(np.sum(weights[k] < 0.1 * np.median(weights[k]))), len(weights[k]))
    rms = [motion_rms(T, points_a[labels == k], points_b[labels == k])
           for k, T in enumerate(transforms)]
    return replace(seg, transforms=transforms, scale=float(transforms[0].scale), rms=rms,
                   weights=w, precisions=precisions), anchors


def fit_covariances(cov: MatchCovariances, background_a: np.ndarray,
                     background_b: np.ndarray, anchors: dict | None, candidates,
                     guided: np.ndarray) -> tuple | None:
    """The covariances of the points :func:`robust_refit` fits, row for row: the matches' (the
    guided ones appended, from their candidates') and the background matches' that anchor each
    link (:func:`anchor_to_background` keeps rows of the background). None when some are not
    known (candidates without covariances)."""
    cov_a, cov_b = cov.matches_a, cov.matches_b
    if len(guided):
        if cov.candidates_a is None or cov.candidates_b is None or candidates is None:
            return None
        rows = []
        for cand, ids in zip(candidates, guided.T, strict=True):
            order = np.argsort(cand.ids)
            rows.append(order[np.searchsorted(cand.ids, ids, sorter=order)])
        cov_a = np.concatenate([cov_a, cov.candidates_a[rows[0]]])
        cov_b = np.concatenate([cov_b, cov.candidates_b[rows[1]]])
    anchor_cov = {}
    if anchors:
        both = np.c_[background_a, background_b]
        tree = cKDTree(both)
        for k, anchor in anchors.items():
            dist, rows = tree.query(np.c_[anchor[0], anchor[1]])
            if len(dist) and dist.max() > 0:
                return None
            anchor_cov[k] = (cov.background_a[rows], cov.background_b[rows])
    return cov_a, cov_b, anchor_cov
