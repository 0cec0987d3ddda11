"""The whole reconstruction: two image folders in, an articulated model out.

Stages (each its own module, plain data between them)::

    sfm (per configuration) -> dense (per configuration) -> object region -> features (A x B)
        -> segment_links -> dense points the table is seen through dropped (artrecon.freespace)
        -> dense points assigned to links -> estimate_joints -> ArticulatedModel

The model frame is configuration A's SfM frame: arbitrary scale and placement when the
cameras were found from the images alone (``model.scale_known`` is False), the frame of the given
camera poses (metres) when poses were given.

Background. The object stands on a table in a room; neither the background nor the object's base
moves between A and B, but the two SfM models are independent, so the background would join the
base link's rigid set (and its points the base link). It is told apart by
:func:`artrecon.dense.object_region`: points far from where the cameras' optical axes meet
(relative to the camera distance) are dropped, and so is the support plane the cameras all look
down on (with everything beyond it). Segmentation and the link point sets use the object only. A
sample of background points is matched as well, for one purpose: the link whose A->B transform
carries the background along is the base, the root of the kinematic tree (without background
matches, the largest link is the root).

Output folder (written whole or not at all: built in a temporary sibling folder, then renamed)::

    OUT/model.json                    the ArticulatedModel (ArticulatedModel.load reads it)
    OUT/links/link_<k>.ply            dense oriented points of each link (model frame)
    OUT/a/sparse/0, OUT/b/sparse/0    the SfM models in COLMAP's layout (+ database.db, colmap.log)
    OUT/a/dense.ply, OUT/b/dense.ply  the object's dense points of each configuration (own frame)
    OUT/a/configuration.json, ...     the per-configuration stage's record and its other files
                                      (the folder contract of artrecon.configuration)
    OUT/matches.npz                   the 3D-3D matches (points_a, points_b, ids, votes, labels,
                                      background_a, background_b)

Running part of it (:data:`STAGES`; ``from_stage``/``to_stage``, the command's ``--from`` and
``--to``). The folder holds the result of two stages, and a run may stop after the first or
start at the second::

    configurations   images -> OUT/a, OUT/b (each: SfM, dense points, object region; written
                     side by side, the record configuration.json last)
    model            OUT/a, OUT/b -> OUT/matches.npz, OUT/links/, OUT/model.json

``to_stage="configurations"`` publishes a folder holding OUT/a and OUT/b only.
``from_stage="model"`` starts from such a folder (or a whole result, with ``overwrite``): each
configuration's record must name the same images, intrinsics, poses, settings, seed and artrecon
version as this run (else InputError naming what differs; they are never recomputed quietly),
and the folder is published again whole, the configurations copied and the model added. The
model is the one the whole run gives, bit for bit (tests/test_stages.py): the whole run reads
configuration B back from its folder too, and A's folder holds what A's stage returned
(artrecon.configuration). Nothing finer is a
stage: a configuration's SfM and dense points share one record, so a folder whose dense stage
failed holds no result a later run could check.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from artrecon import workers
from artrecon._version import __version__
from artrecon.assign import AssignConfig, assign_dense_to_links, views_from_sfm
from artrecon.confidence import (
    ConfidenceConfig,
    assess_joints,
    check_motion,
    explain_segmentation_failure,
)
from artrecon.configuration import (
    Configuration,
    check_reusable,
    load_configuration,
    reconstruct_configuration,
    stage_settings,
)
from artrecon.dense import DenseConfig, RegionConfig
from artrecon.errors import (
    DegenerateError,
    InputError,
    ReconstructionError,
    WeakEvidenceError,
)
from artrecon.features import (
    GuidedConfig,
    MatchConfig,
    PointDescriptors,
    guided_matches,
    match_configurations,
    point_descriptors,
    tracked_features,
)
from artrecon.files import (
    check_output_dir,
    check_output_path,
    make_work_dir,
    publish_dir,
    write_ply,
)
from artrecon.freespace import FreeSpaceConfig, seen_through_table, support_plane
from artrecon.geometry import rotation_angle
from artrecon.io import (
    Intrinsics,
    check_distinct,
    load_cameras_json,
    load_image_folder,
    parse_intrinsics,
)
from artrecon.joints import JointConfig, KinematicTree, build_kinematic_tree, estimate_joints
from artrecon.model import ArticulatedModel, Link
from artrecon.procrustes import (
    rigid_transform,
    robust_shared_scale_transforms,
    shared_scale_transforms,
)
from artrecon.segment import (
    Segmentation,
    SegmentationConfig,
    min_link_size,
    segment_links,
)
from artrecon.settings import apply_settings
from artrecon.sfm import SfMConfig, camera_summary
from artrecon.uncertainty import MatchCovariances, point_covariances, robust_gls_transforms

log = logging.getLogger(__name__)

#: The stages a run can start at or stop after (:func:`reconstruct`'s ``from_stage`` and
#: ``to_stage``, the command's ``--from`` and ``--to``), in order, with what each leaves in the
#: output folder for the next. Only these two: the output folder keeps nothing finer that a
#: later run could check and start from (a configuration's SfM and dense points are one record,
#: :mod:`artrecon.configuration`; matches, links and joints are saved together).
STAGES = {
    "configurations": "OUT/a and OUT/b: each configuration's cameras (SfM), dense points and "
                      "object region",
    "model": "OUT/matches.npz, OUT/links/, OUT/model.json: matches across A and B, links, "
             "joints",
}
#: Files that tell a folder written by :func:`reconstruct` (whole, or stopped after the
#: configurations) from any other folder.
OUTPUT_MARKERS = ("model.json", "a/configuration.json", "b/configuration.json")

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


@dataclass(frozen=True)
class ReconstructConfig:
    """Settings of every stage."""

    sfm: SfMConfig = field(default_factory=SfMConfig)
    dense: DenseConfig = field(default_factory=DenseConfig)
    region: RegionConfig = field(default_factory=RegionConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    joints: JointConfig = field(default_factory=JointConfig)
    assign: AssignConfig = field(default_factory=AssignConfig)
    freespace: FreeSpaceConfig = field(default_factory=FreeSpaceConfig)
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)
    guided: GuidedConfig = field(default_factory=GuidedConfig)


def with_settings(config: ReconstructConfig, settings: dict[str, float | int | bool | str]
                  ) -> ReconstructConfig:
    """``config`` with some settings changed, each named ``"stage.field"`` as in
    :class:`ReconstructConfig` (e.g. ``{"dense.downsample": 1}``: full-resolution stereo for
    thin objects). Each value is checked against the field's range and converted to its type
    (:func:`artrecon.settings.apply_settings`); an unknown stage or field, or a value of the wrong
    kind, not finite or out of range, raises InputError naming the valid range."""
    return apply_settings(config, settings)


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
    from artrecon.procrustes import rotation_angle

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
                    disp = _rms(transforms[i], points_a[mj], transforms[j].apply(points_a[mj]))
                    noise = max(_rms(transforms[i], points_a[mi], points_b[mi]),
                                _rms(transforms[j], points_a[mj], points_b[mj]))
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


def blame_poses(err: Exception, sfms: dict, config: SfMConfig) -> Exception:
    """``err`` (a segmentation or joint-evidence failure) with the given camera poses named as its
    likely cause, when they were given and agree with the images worse than
    ``config.suspect_pose_epipolar_px`` (though well enough to pass the pose check); else ``err``.

    Slightly wrong poses (encoder noise, a camera mount error) put each configuration's points
    in slightly different wrong places, so the matches across configurations stop moving
    together, and segmentation blames the matches ("chance pairings", "too few inliers").
    """
    figures = {k: s.pose_agreement["epipolar_median_px"] for k, s in sfms.items()
               if s.pose_agreement and s.pose_agreement.get("epipolar_median_px") is not None}
    if not any(v > config.suspect_pose_epipolar_px for v in figures.values()):
        return err
    note = (" Likely cause: the given camera poses. They passed the pose check but agree with the "
            "images only to a median " + ", ".join(f"{v:.2f} px ({k.upper()})"
                                                   for k, v in sorted(figures.items()))
            + " from the epipolar lines they predict (exact poses: ~0.1 px); such poses "
            "(a hand-eye / camera mount calibration error, arm encoder errors) put the points of "
            "the two configurations in differently wrong places, so their matches no longer move "
            "together. Run without the poses (without --use-poses) so SfM recovers the cameras "
            "from the images, or recalibrate the camera mount and the arm.")
    if isinstance(err, WeakEvidenceError):
        return WeakEvidenceError(str(err) + note, err.records)
    try:
        return type(err)(str(err) + note)
    except TypeError:  # an error class with another constructor
        return ReconstructionError(str(err) + note)


def _rms(T, pa: np.ndarray, pb: np.ndarray) -> float:
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
    rms_own = _rms(seg.transforms[root], own_a, own_b)
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
    rms_anchored = _rms(transforms[root], own_a, own_b)
    if rms_anchored > ANCHOR_MAX_RMS_GROWTH * rms_own:
        log.warning("base link %d: fitted with the background its matches' residual grows from "
                    "%.3g to %.3g RMS; the base moved against the room, its motion is fitted to "
                    "its own matches", root, rms_own, rms_anchored)
        return seg, None
    log.info("base link %d anchored to %d background matches (its matches' RMS %.3g -> %.3g)",
             root, used.sum(), rms_own, rms_anchored)
    rms = [_rms(T, a, b) for T, (a, b) in zip(transforms, groups, strict=True)]
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
        rms = [_rms(T, pa[labels == k], pb[labels == k]) for k, T in enumerate(transforms)]
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
    rms = [_rms(T, points_a[labels == k], points_b[labels == k])
           for k, T in enumerate(transforms)]
    return replace(seg, transforms=transforms, scale=float(transforms[0].scale), rms=rms,
                   weights=w, precisions=precisions), anchors


@dataclass
class Articulation:
    """What :func:`articulate` finds in the matches: links, tree, joints and their evidence."""

    segmentation: Segmentation
    """The matches' links, the base's motion anchored to the background."""
    root: int | None
    """The base (the link the background moves with), None when the background does not show it
    (the tree's root is then the largest link)."""
    anchors: dict | None
    """``{root: (background_a, background_b)}``: the background matches the base was fitted to."""
    labels_a: np.ndarray
    """Link of each dense point of A (-1: none)."""
    labels_b: np.ndarray
    """Link of each dense point of B."""
    links: list[Link]
    tree: KinematicTree
    joints: list
    confidence: dict
    """:func:`artrecon.confidence.assess_joints`' summary (each joint's record is also in
    ``Joint.confidence``)."""
    timings: dict[str, float]
    points_a: np.ndarray | None = None
    """The matches the links were fitted to (the guided ones appended), A's frame ..."""
    points_b: np.ndarray | None = None
    """... and B's; ``segmentation.labels`` labels them."""
    guided_ids: np.ndarray | None = None
    """(m, 2) SfM point ids (A, B) of the matches the guided matching appended."""


def articulate(points_a: np.ndarray, points_b: np.ndarray, background_a: np.ndarray,
               background_b: np.ndarray, dense_a, dense_b, config: ReconstructConfig, seed: int,
               *, views_a=None, views_b=None, occluders_a=None, occluders_b=None,
               candidates: tuple[PointDescriptors, PointDescriptors] | None = None,
               covariances: MatchCovariances | None = None) -> Articulation:
    """Every step after matching: segment the matches into links (method step 2), anchor the
    base to the background, label the dense points with links, build the kinematic tree on the
    links' dense points, estimate each joint (step 3) and check its evidence.

    The one place these steps and their order live: the pipeline and the robustness harness
    (sim.perturb.resegment, which re-runs them on corrupted matches) both call it.

    Parameters
    ----------
    points_a, points_b : (n, 3)
        The object's cross-configuration matches (A's and B's frames).
    background_a, background_b : (m, 3)
        Matches on the static background (may be empty).
    dense_a, dense_b : artrecon.dense.DensePoints
    views_a, views_b, occluders_a, occluders_b :
        The image cues of the dense labelling (artrecon.assign); without them the labelling is
        geometric only.
    candidates : (PointDescriptors, PointDescriptors), optional
        The object's SfM points of A and B that the matching left out, for the guided matching
        (:func:`add_guided_matches`, ``config.guided``); without them only the matches count.
    covariances : artrecon.uncertainty.MatchCovariances, optional
        The triangulation covariances of the matches', background matches' and candidates'
        points (row for row): the links' motions are then fitted with them
        (:func:`robust_refit`); without them (or with ``config.segmentation.covariances``
        off), isotropically.

    Raises
    ------
    DegenerateError
        Fewer than two links (explained: no motion, one rigid body, chance pairings ...).
    WeakEvidenceError
        A joint's evidence is too weak for its axis (artrecon.confidence).
    """
    # One BLAS thread: these steps multiply many small matrices ((n, 3) points by a rotation),
    # for which a second BLAS thread only adds its start-up and spinning (40 ms instead of 1 ms
    # of CPU per product of 150k points on this 2-core machine); the results are the same. The
    # two configurations' work runs side by side instead.
    with workers.single_threaded():
        return _articulate(points_a, points_b, background_a, background_b, dense_a, dense_b,
                           config, seed, views_a=views_a, views_b=views_b,
                           occluders_a=occluders_a, occluders_b=occluders_b,
                           candidates=candidates, covariances=covariances)


def _articulate(points_a, points_b, background_a, background_b, dense_a, dense_b,
                config: ReconstructConfig, seed: int, *, views_a, views_b, occluders_a,
                occluders_b, candidates, covariances=None) -> Articulation:
    timings: dict[str, float] = {}
    t = time.perf_counter()
    # nothing moved, or the whole object did: said first and plainly (NoMotionError, ...)
    check_motion(points_a, points_b, background_a, background_b, config.segmentation, seed)
    try:
        seg = segment_links(points_a, points_b, config.segmentation, seed=seed)
        seg = merge_equivalent_links(points_a, points_b, seg)
        if seg.n_links < 2:
            n = len(points_a)
            left = int((seg.labels < 0).sum())
            least = min_link_size(config.segmentation, n)
            raise DegenerateError(
                f"the matches form {seg.n_links} rigid link(s), an articulated object needs at "
                f"least 2: either the object moved as one rigid body (move a joint between the "
                f"two captures), or its moving part has too few matches to be found ({left} of "
                f"the {n} matches fit no link, a link needs at least {least}): photograph it "
                "with more views, in sharper images or with more texture on it.")
    except DegenerateError as exc:  # fewer than two links: one moving body, or other objects?
        raise explain_segmentation_failure(exc, points_a, points_b, config.segmentation,
                                           seed) from exc
    # The base moves with the room: its motion is fitted to the background matches too.
    seg, root, anchors = anchor_base(points_a, points_b, seg, background_a, background_b)
    guided = np.zeros((0, 2), np.int64)
    if candidates is not None and config.guided.enabled:
        points_a, points_b, seg, guided = add_guided_matches(points_a, points_b, seg, candidates,
                                                             anchors, config.guided)
    fit_covariances = None
    if covariances is not None and config.segmentation.covariances:
        fit_covariances = _fit_covariances(covariances, background_a, background_b, anchors,
                                           candidates, guided)
    seg, anchors = robust_refit(points_a, points_b, seg, anchors, fit_covariances)
    timings["segment"] = time.perf_counter() - t
    t = time.perf_counter()
    # dense points the table is seen through (fattened edges of thin links) join no link
    drop_a, drop_b = workers.side_by_side(
        lambda: table_free_space(dense_a.points, views_a, occluders_a, config, seed),
        lambda: table_free_space(dense_b.points, views_b, occluders_b, config, seed))
    # the table next to the object is static: Potts neighbours that move as the base does
    lab_a, lab_b = assign_dense_to_links(
        dense_a.subset(~drop_a), dense_b.subset(~drop_b), points_a, points_b, seg,
        views_a=views_a, views_b=views_b, occluders_a=occluders_a, occluders_b=occluders_b,
        config=config.assign, base=root, static_a=table_points(occluders_a, dense_a.points),
        static_b=table_points(occluders_b, dense_b.points))
    lab_a = _expand(lab_a, ~drop_a)
    lab_b = _expand(lab_b, ~drop_b)
    seg, root, anchors, lab_a, lab_b, unsupported = drop_unsupported_links(
        seg, root, anchors, lab_a, lab_b)
    if seg.n_links < 2:
        raise DegenerateError(
            f"of the {seg.n_links + len(unsupported)} links the matches form, only "
            f"{seg.n_links} holds any of the dense surface (the others' matches are "
            "chance pairings): the object moved as one rigid body, or its moving part was not "
            "seen well enough; photograph it with more views or more texture")
    links = links_from_labels(dense_a, dense_b, lab_a, lab_b, seg.transforms)
    timings["assign"] = time.perf_counter() - t
    t = time.perf_counter()
    # Adjacency on the links' dense surfaces: the matches are sparse where links meet.
    tree = build_kinematic_tree(points_a, seg, config.joints,
                                link_points=[lk.points for lk in links])
    if root is None:
        log.warning("the background does not show which link is the base; the largest link "
                    "(%d) is taken as the root", tree.root)
    elif root != tree.root:
        tree = reroot(tree, root)
    joints = estimate_joints(points_a, points_b, seg, config.joints, tree=tree)
    # Evidence per joint (Joint.confidence); raises WeakEvidenceError rather than a wrong axis.
    confidence = assess_joints(points_a, points_b, seg, joints, config.joints, config.confidence,
                               seed, anchors)
    timings["joints"] = time.perf_counter() - t
    return Articulation(seg, root, anchors, lab_a, lab_b, links, tree, joints, confidence,
                        timings, points_a, points_b, guided)


def _fit_covariances(cov: MatchCovariances, background_a: np.ndarray,
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


def drop_unsupported_links(seg: Segmentation, root: int | None, anchors: dict | None,
                           labels_a: np.ndarray, labels_b: np.ndarray):
    """Remove the links that the dense labelling gave no point of either configuration.

    Every link of the object has a surface the cameras saw (its matches are features on it), and
    the labelling offers each dense point to every link: a link that wins none is a set of
    matches that happen to move together (chance pairings on repeated texture, seen on
    pliers_panda: 21 matches, after sequential RANSAC split the mismatches into small "links"),
    not a part. Left in, it has no points to say where it meets the others (the kinematic tree
    cannot place it) and would become an invented joint. Its matches become outliers.

    Returns
    -------
    seg, root, anchors, labels_a, labels_b
        Renumbered (the remaining links keep their order).
    dropped : list of int
        The removed links, by their former numbers.
    """
    counts = (np.bincount(labels_a[labels_a >= 0], minlength=seg.n_links)[:seg.n_links]
              + np.bincount(labels_b[labels_b >= 0], minlength=seg.n_links)[:seg.n_links])
    dropped = [int(k) for k in np.flatnonzero(counts == 0)]
    if not dropped:
        return seg, root, anchors, labels_a, labels_b, dropped
    if root in dropped:
        raise ReconstructionError(f"the base link ({root}, the one the background moves with) "
                                  "holds none of the dense surface; reconstruct again with more "
                                  "views of the object")
    keep = [k for k in range(seg.n_links) if k not in dropped]
    remap = np.full(seg.n_links + 1, -1)  # the last entry maps -1 to -1
    remap[keep] = np.arange(len(keep))
    for k in dropped:
        log.warning("link %d (%d matches) holds none of the dense surface of A or B: dropped, "
                    "its matches taken for chance pairings", k, int(seg.sizes[k]))

    def pick(values):
        return [values[k] for k in keep] if values else values

    seg = replace(seg, labels=remap[seg.labels], transforms=pick(seg.transforms),
                  thresholds=pick(seg.thresholds), rms=pick(seg.rms))
    if anchors:
        anchors = {int(remap[k]): v for k, v in anchors.items() if k in keep}
    root = None if root is None else int(remap[root])
    return seg, root, anchors, remap[labels_a], remap[labels_b], dropped


def table_free_space(points: np.ndarray, views, occluders, config: ReconstructConfig,
                     seed: int) -> np.ndarray:
    """Mask (n,) of the dense points of one configuration that its views see the table through
    (:func:`artrecon.freespace.seen_through_table`); none without colour views or occluders (the
    dense points the support plane is fitted to, as the object region fits it)."""
    drop = np.zeros(len(points), bool)
    if (not config.freespace.enabled or not views or occluders is None or len(points) == 0
            or any(v.colour is None for v in views)):
        return drop
    centres = np.array([v.centre for v in views])
    axes = np.array([v.T_cw[2, :3] for v in views])
    r = config.region
    plane = support_plane(occluders, centres, axes, radius_fraction=r.radius_fraction,
                          tolerance=r.plane_tolerance, min_fraction=r.plane_min_fraction,
                          iterations=r.plane_iterations, seed=seed)
    return seen_through_table(points, views, plane, config.freespace, seed)


def table_points(occluders: np.ndarray | None, object_points: np.ndarray) -> np.ndarray | None:
    """The dense points of one configuration that the object region took for the background
    (``occluders``, all its dense points, less the object's ``object_points``). Next to the object
    these are the table it stands on (and the base's lowest millimetres, cut with the table):
    static, they move as the base does. None without occluders."""
    if occluders is None or len(occluders) == 0:
        return None
    occluders = np.asarray(occluders, float)
    if len(object_points) == 0:
        return occluders
    # the object's points are the same numbers in both arrays (artrecon.configuration); if they
    # are not (occluders from elsewhere), the object's own surface would pass for the table
    # (only equal points matter: a tiny search bound spares the far table a full search,
    # 0.2 instead of 17 CPU s for the 0.9 M occluders of scissors)
    d = cKDTree(np.asarray(object_points, float)).query(occluders, distance_upper_bound=1e-12)[0]
    if np.count_nonzero(d == 0) < 0.5 * len(object_points):
        log.warning("the occluders do not hold the object's dense points; the table is left out "
                    "of the dense labelling")
        return None
    return occluders[d > 0]


def _expand(labels: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Labels of the kept points spread back over all points (-1: dropped)."""
    out = np.full(len(kept), -1, dtype=np.asarray(labels).dtype if len(labels) else int)
    out[kept] = labels
    return out


def tree_record(tree: KinematicTree) -> dict:
    """The tree's choice, for model.json: its edges, its margin over the next best tree and every
    adjacent pair's figures (:attr:`KinematicTree.edge_figures`)."""
    return {"edges": [list(e) for e in tree.edges], "root": int(tree.root),
            "margin": float(tree.margin) if np.isfinite(tree.margin) else None,
            "pairs": [{"links": list(pair), **{k: (list(v) if isinstance(v, tuple) else v)
                                               for k, v in fig.items()}}
                      for pair, fig in sorted(tree.edge_figures.items())]}


def reroot(tree: KinematicTree, root: int) -> KinematicTree:
    """The same tree with another root (edges re-oriented, breadth-first from the new root)."""
    n = len(tree.parents)
    nbrs: dict[int, list[int]] = {k: [] for k in range(n)}
    for p, c in tree.edges:
        nbrs[p].append(c)
        nbrs[c].append(p)
    parents = np.full(n, -1)
    edges, queue, seen = [], [root], {root}
    while queue:
        u = queue.pop(0)
        for v in sorted(nbrs[u]):
            if v not in seen:
                seen.add(v)
                parents[v] = u
                edges.append((u, v))
                queue.append(v)
    # the pairs' figures, costs and margin do not depend on the root
    return replace(tree, root=root, parents=parents, edges=edges)


def _resolve_inputs(images, intrinsics, poses_arg, which: str):
    iset = load_image_folder(images)
    intr = None
    poses = None
    if intrinsics is not None:
        intr = parse_intrinsics(intrinsics, iset.size)
    elif iset.cameras_file is not None:
        intr = load_cameras_json(iset.cameras_file)[0]
        log.info("configuration %s: intrinsics from %s", which, iset.cameras_file)
    if poses_arg is True:
        if iset.cameras_file is None:
            raise InputError(f"poses requested but {iset.root} has no cameras.json; run without "
                             "poses (SfM from the images) or add the camera file")
        intr_c, poses = load_cameras_json(iset.cameras_file)
        intr = intr or intr_c
    elif isinstance(poses_arg, dict):
        poses = {Path(k).name: np.asarray(v, dtype=float) for k, v in poses_arg.items()}
    if poses is not None and intr is None:
        raise InputError(f"configuration {which}: camera poses need intrinsics too")
    if intr is not None and intr.size is not None and tuple(intr.size) != tuple(iset.size):
        raise InputError(f"configuration {which}: intrinsics are for {intr.size[0]}x{intr.size[1]}"
                         f" images but {iset.image_dir} holds {iset.size[0]}x{iset.size[1]}")
    return iset, intr, poses


def reconstruct(images_a, images_b, *, intrinsics=None, poses=None, out_dir=None, seed: int = 0,
                config: ReconstructConfig = ReconstructConfig(), overwrite: bool = False,
                progress: bool = True, jobs: int = 2, configurations: tuple | None = None,
                from_stage: str = "configurations", to_stage: str = "model"
                ) -> ArticulatedModel | None:
    """Articulated model of an object from two image sets, one per configuration.

    The whole run by default; ``from_stage`` and ``to_stage`` run part of it (:data:`STAGES`):
    ``to_stage="configurations"`` writes ``out_dir/a`` and ``out_dir/b`` and stops, and
    ``from_stage="model"`` starts from those of an existing ``out_dir`` and adds the model to
    it. The two halves give the model the whole run gives (same inputs, settings and seed).

    Parameters
    ----------
    images_a, images_b : str or Path
        Folders of photos of configuration A and B (or capture folders with ``images/``).
    intrinsics : (3, 3) array, "fx,fy,cx,cy", JSON path, Intrinsics, or a pair of them, optional
        Known pinhole intrinsics (held fixed). When absent, a folder's ``cameras.json`` supplies
        them if present; otherwise COLMAP estimates them.
    poses : None, True, or a pair of dicts name -> (4, 4) ``T_world_camera``
        None (default, the method): cameras from the images alone. True: use each folder's
        ``cameras.json`` poses (the arm's forward kinematics) and only triangulate.
    out_dir : str or Path, optional
        Where to write the model, link PLYs and SfM models (see the module docstring), whole or
        not at all. Nothing is kept when None (then only the whole run).
    seed : int
    config : ReconstructConfig
    overwrite : bool
        Replace an existing ``out_dir`` (only a folder this function wrote: one holding
        ``model.json`` or the configurations' records). With ``from_stage="model"``: replace the
        model of an ``out_dir`` that holds one (its configurations are kept).
    progress : bool
        tqdm bars on stderr.
    jobs : int
        Processes for the per-configuration stage (:mod:`artrecon.configuration`): 2 runs
        configuration B beside A; 1 runs them one after the other (same result).
    configurations : (folder_a, folder_b), optional
        Folders of finished per-configuration stages of these image sets (e.g. written by the
        harness while it captured): reused when their records name the same inputs and
        settings, recomputed otherwise. Not with ``from_stage="model"``.
    from_stage, to_stage : {"configurations", "model"}
        The first and the last stage to run (:data:`STAGES`). ``from_stage="model"`` needs the
        ``out_dir`` of an earlier run of these inputs, settings and seed (stopped after the
        configurations, or whole); their records are checked, never recomputed.

    Returns
    -------
    ArticulatedModel or None
        Links with dense oriented points (model frame = configuration A's SfM frame), joints;
        None when the run stops after the configurations.

    Raises
    ------
    InputError
        Bad folders, images or camera files; an unknown stage, ``from_stage`` after
        ``to_stage``, or (``from_stage="model"``) an ``out_dir`` without finished
        configurations of these inputs and settings (the message says what differs).
    ReconstructionError, DegenerateError
        A stage failed (the message says which and what to try). WeakEvidenceError (a
        ReconstructionError): a joint's evidence is too weak to give its axis
        (artrecon.confidence; each joint of a returned model has its ``confidence`` record).
        PoseMismatchError (a ReconstructionError): the given ``poses`` disagree with the images
        (artrecon.sfm.check_pose_agreement; a returned model records the figures in
        ``metadata["pose_agreement"]``).
    """
    t_all = time.perf_counter()
    first, last = _stage_range(from_stage, to_stage)
    if (first, last) != (0, len(STAGES) - 1) and out_dir is None:
        raise InputError(f"a run from stage {from_stage!r} to {to_stage!r} needs an output "
                         "folder (out_dir): the stages meet there")
    if first > 0 and configurations is not None:
        raise InputError(f"from stage {from_stage!r}, the configurations are those of out_dir; "
                         "give configurations= only to a run from the start")
    # One value for both sets, or a pair (a (3, 3) nested list has 3 rows, never 2).
    pair = intrinsics if isinstance(intrinsics, (tuple, list)) and len(intrinsics) == 2 \
        else (intrinsics, intrinsics)
    poses_pair = poses if isinstance(poses, (tuple, list)) else (poses, poses)
    # every image is decoded once here (checked, thumbnails): A's and B's side by side (A's
    # error, if both are bad)
    with workers.single_threaded():
        (set_a, intr_a, poses_a), (set_b, intr_b, poses_b) = workers.side_by_side(
            lambda: _resolve_inputs(images_a, pair[0], poses_pair[0], "A"),
            lambda: _resolve_inputs(images_b, pair[1], poses_pair[1], "B"))
    check_distinct(set_a, set_b)
    if out_dir is not None:
        out_dir = _check_output(out_dir, [set_a.root, set_a.image_dir, set_b.root,
                                          set_b.image_dir], overwrite, from_stage,
                                example=set_a.root.parent / "model")
    if first > 0:  # the configurations of out_dir, exactly as this run would compute them
        settings = stage_settings(config.sfm, config.dense, config.region)
        restart = ("start from the configurations instead (without --from, "
                   "from_stage='configurations'), which recomputes them")
        for key, iset, intr, known in (("a", set_a, intr_a, poses_a),
                                       ("b", set_b, intr_b, poses_b)):
            check_reusable(out_dir / key, iset, intr, known, settings, seed,
                           which=key.upper(), restart=restart)
        configurations = (out_dir / "a", out_dir / "b")
    if out_dir is not None:
        work = make_work_dir(out_dir)  # also removes those of interrupted runs
    else:
        work = Path(tempfile.mkdtemp(prefix="artrecon-"))
    try:
        model = _run(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed, config,
                     progress, jobs, configurations, reuse_only=first > 0,
                     stop_after_configurations=last == 0)
        if model is not None:
            model.metadata["timings"]["total"] = time.perf_counter() - t_all
        if out_dir is not None:
            if model is not None:
                model.save(work / "model.json")
            publish_dir(work, out_dir)
            log.info("wrote %s", out_dir)
    finally:
        if work.exists():
            shutil.rmtree(work, ignore_errors=True)
    return model


def _stage_range(from_stage: str, to_stage: str) -> tuple[int, int]:
    """Indices in :data:`STAGES` of the first and the last stage to run (InputError for an
    unknown stage or a first stage after the last)."""
    names = list(STAGES)
    for flag, name in (("--from", from_stage), ("--to", to_stage)):
        if name not in STAGES:
            listing = "; ".join(f"{k} (writes {v})" for k, v in STAGES.items())
            raise InputError(f"{flag} {name}: no such stage. The stages, in order: {listing}")
    first, last = names.index(from_stage), names.index(to_stage)
    if first > last:
        raise InputError(f"--from {from_stage} comes after --to {to_stage}, so there is nothing "
                         f"to run; the stages in order: {', '.join(names)}")
    return first, last


def _check_output(out_dir, inputs, overwrite: bool, from_stage: str, example) -> Path:
    """The output folder of a run from ``from_stage``: a new folder (or, with ``overwrite``, an
    earlier result) for a run from the start; for a later start, an existing folder of an
    earlier run, holding no model unless ``overwrite`` (its configurations are checked by the
    caller, against this run's inputs)."""
    out_dir = Path(out_dir)
    check_output_path(out_dir, inputs, example=example)
    holds_model = (out_dir / "model.json").exists()
    if from_stage == "configurations":
        if (out_dir.is_dir() and not overwrite and not holds_model
                and (out_dir / "a" / "configuration.json").is_file()):
            raise InputError(f"output folder {out_dir} exists and holds the configurations of a "
                             "run stopped after them (--to configurations): continue it with "
                             "--from model, or pass --overwrite to start it over")
        return check_output_dir(out_dir, inputs, overwrite=overwrite, marker=OUTPUT_MARKERS,
                                example=example)
    if out_dir.is_symlink() or not out_dir.is_dir():
        raise InputError(f"--from {from_stage}: {out_dir} is not a folder; --out must name the "
                         "output folder of an earlier run of these images (whole, or stopped "
                         "with --to configurations): run without --from to start from the "
                         "beginning")
    if holds_model and not overwrite:
        raise InputError(f"--from {from_stage}: {out_dir} holds a model already (model.json); "
                         "pass --overwrite to replace it (its configurations are kept), or "
                         "choose another --out")
    return out_dir


def prepare_configuration(images, out_dir, *, intrinsics=None, poses=None, seed: int = 0,
                          config: ReconstructConfig = ReconstructConfig(), which: str = "",
                          progress: bool = False) -> Path:
    """The per-configuration stage of one image set (:mod:`artrecon.configuration`), written
    to ``out_dir`` for a later :func:`reconstruct` (``configurations=``) to start from.

    ``images``, ``intrinsics`` and ``poses`` are one configuration's, as :func:`reconstruct`
    takes them. Returns ``out_dir``.
    """
    iset, intr, known = _resolve_inputs(images, intrinsics, poses, which or "?")
    _configuration(iset, Path(out_dir), intr, known, config, seed, which, progress)
    return Path(out_dir)


def _configuration(iset, folder, intr, poses, config: ReconstructConfig, seed: int, which: str,
                   progress: bool) -> Configuration:
    return reconstruct_configuration(iset, folder, intr, poses, sfm_config=config.sfm,
                                     dense_config=config.dense, region_config=config.region,
                                     seed=seed, which=which, progress=progress)


def _configuration_in_process(*args) -> None:
    """:func:`_configuration` in a worker process: the folder is the result (a pycolmap
    Reconstruction does not cross processes)."""
    _configuration(*args)


def _run(set_a, set_b, intr_a: Intrinsics | None, intr_b: Intrinsics | None, poses_a, poses_b,
         work: Path, seed: int, config: ReconstructConfig, progress: bool, jobs: int = 2,
         configurations: tuple | None = None, reuse_only: bool = False,
         stop_after_configurations: bool = False) -> ArticulatedModel | None:
    """The stages into ``work``: the configurations (computed, or reused from copies of
    ``configurations``; only read back when ``reuse_only``, the caller having checked them),
    then, unless ``stop_after_configurations``, the model (returned)."""
    timings: dict[str, float] = {}
    folders = {"a": work / "a", "b": work / "b"}
    if configurations is not None:  # finished per-configuration folders: start from copies
        for key, src in zip(("a", "b"), configurations, strict=True):
            if Path(src).is_dir():
                shutil.copytree(src, folders[key], symlinks=True)
    args = {"a": (set_a, folders["a"], intr_a, poses_a, config, seed, "A"),
            "b": (set_b, folders["b"], intr_b, poses_b, config, seed, "B")}
    confs: dict[str, Configuration] = {}
    if reuse_only:
        confs = {key: load_configuration(folder) for key, folder in folders.items()}
    elif jobs > 1:
        # B in a second (spawned) process while this one does A: the two are independent
        with workers.pool(1) as pool:
            # the worker ignores Ctrl-C; this process stops it (one line, no worker traceback)
            future = workers.submit(pool, _configuration_in_process, *args["b"], False)
            try:
                confs["a"] = _configuration(*args["a"], progress)
                future.result()
            except KeyboardInterrupt:
                workers.stop(pool)
                raise
        if stop_after_configurations:
            return None
        confs["b"] = load_configuration(folders["b"])
    else:
        for key in ("a", "b"):
            confs[key] = _configuration(*args[key], progress)
    if stop_after_configurations:
        return None
    for key, conf in confs.items():
        timings[f"sfm_{key}"] = conf.record["timings"]["sfm"]
        timings[f"dense_{key}"] = conf.record["timings"]["dense"]
    sfms = {k: c.sfm for k, c in confs.items()}
    denses = {k: c.dense for k, c in confs.items()}
    occluders = {k: c.occluders for k, c in confs.items()}
    regions = {k: c.object_ids for k, c in confs.items()}
    backgrounds = {k: c.background_ids for k, c in confs.items()}
    with workers.single_threaded():
        return _after_configurations(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work, seed,
                                     config, sfms, denses, occluders, regions, backgrounds,
                                     timings)


def _after_configurations(set_a, set_b, intr_a, intr_b, poses_a, poses_b, work: Path, seed: int,
                          config: ReconstructConfig, sfms: dict, denses: dict, occluders: dict,
                          regions: dict, backgrounds: dict, timings: dict) -> ArticulatedModel:
    """:func:`_run` from the two configurations on (one BLAS and OpenCV thread per task, A's
    and B's own work side by side)."""
    t = time.perf_counter()
    feats = {k: tracked_features(sfms[k], regions[k] | backgrounds[k]) for k in ("a", "b")}
    matches = match_configurations(sfms["a"], sfms["b"], config.match, seed,
                                   features=(feats["a"], feats["b"]))
    in_a = np.isin(matches.point3D_ids_a, list(regions["a"]))
    in_b = np.isin(matches.point3D_ids_b, list(regions["b"]))
    background = matches.subset(~in_a & ~in_b)
    matches = matches.subset(in_a & in_b)
    # the object's points the matching left out, for the guided matching
    candidates = []
    for key, matched in (("a", matches.point3D_ids_a), ("b", matches.point3D_ids_b)):
        desc = point_descriptors(sfms[key], feats[key])
        keep = np.isin(desc.ids, list(regions[key])) & ~np.isin(desc.ids, matched)
        candidates.append(PointDescriptors(desc.ids[keep], desc.xyz[keep], desc.desc[keep]))
    # how precisely each point is known (its track's views), for the links' motions
    covariances = None
    if config.segmentation.covariances:
        cov = {}
        for key in ("a", "b"):
            rec = sfms[key].reconstruction
            ids_m = matches.point3D_ids_a if key == "a" else matches.point3D_ids_b
            ids_g = background.point3D_ids_a if key == "a" else background.point3D_ids_b
            ids_c = candidates[0 if key == "a" else 1].ids
            cov[key] = [point_covariances(rec, ids) for ids in (ids_m, ids_g, ids_c)]
        covariances = MatchCovariances(cov["a"][0], cov["b"][0], cov["a"][1], cov["b"][1],
                                       cov["a"][2], cov["b"][2])
    timings["match"] = time.perf_counter() - t
    views_a, views_b = workers.side_by_side(lambda: views_from_sfm(sfms["a"]),
                                            lambda: views_from_sfm(sfms["b"]))
    try:
        art = articulate(matches.points_a, matches.points_b, background.points_a,
                         background.points_b, denses["a"], denses["b"], config, seed,
                         views_a=views_a, views_b=views_b,
                         occluders_a=occluders["a"], occluders_b=occluders["b"],
                         candidates=tuple(candidates), covariances=covariances)
    except (DegenerateError, WeakEvidenceError) as exc:
        # slightly wrong given poses show up as matches that do not move together
        raise blame_poses(exc, sfms, config.sfm) from exc
    timings.update(art.timings)
    seg, links, root = art.segmentation, art.links, art.root
    np.savez(work / "matches.npz", points_a=art.points_a, points_b=art.points_b,
             point3D_ids_a=np.r_[matches.point3D_ids_a, art.guided_ids[:, 0]],
             point3D_ids_b=np.r_[matches.point3D_ids_b, art.guided_ids[:, 1]],
             votes=np.r_[matches.votes, np.zeros(len(art.guided_ids), np.int64)],
             labels=seg.labels, background_a=background.points_a,
             background_b=background.points_b)
    (work / "links").mkdir(exist_ok=True)
    for k, lk in enumerate(links):
        write_ply(work / "links" / f"link_{k}.ply", lk.points, lk.normals, lk.colours)
    metric = poses_a is not None and poses_b is not None
    model = ArticulatedModel(
        links=links, joints=art.joints, scale=1.0,
        frames={"T_world_model": np.eye(4)} if metric else {},
        root=art.tree.root, scale_a_to_b=float(seg.scale), scale_known=metric,
        metadata={
            "artrecon_version": __version__, "seed": seed,
            "images_a": str(set_a.root), "images_b": str(set_b.root),
            "camera_poses": "given (known-pose triangulation)" if metric else "SfM from images",
            # given poses against the images, per configuration (artrecon.sfm.pose_agreement)
            "pose_agreement": {k: s.pose_agreement for k, s in sfms.items()
                               if s.pose_agreement is not None} or None,
            "model_frame": "world frame of configuration A's camera poses (metres)" if metric
            else "configuration A's SfM frame (arbitrary scale)",
            # the focal length SfM used: given, from EXIF, or self-calibrated (and refined)
            "intrinsics": {k: camera_summary(s.reconstruction, intr is not None,
                                             s.model_dir.parents[1])
                           for (k, s), intr in zip(sfms.items(), (intr_a, intr_b), strict=True)},
            "registered_images": {k: s.reconstruction.num_reg_images() for k, s in sfms.items()},
            "num_images": {k: s.num_images for k, s in sfms.items()},
            "sparse_points": {k: s.reconstruction.num_points3D() for k, s in sfms.items()},
            "dense_points": {k: len(d) for k, d in denses.items()},
            "matches": len(matches), "guided_matches": len(art.guided_ids),
            "match_outliers": int((seg.labels < 0).sum()),
            "background_matches": len(background),
            "root_from": "background" if root is not None else "largest link",
            "root_background_matches": len(art.anchors[root][0]) if art.anchors else 0,
            "link_matches": seg.sizes.tolist(),
            "confidence": art.confidence,
            # every adjacent pair's figures and how clearly the tree won (artrecon.joints)
            "kinematic_tree": tree_record(art.tree),
            "dense_unassigned": {"a": int((art.labels_a < 0).sum()),
                                 "b": int((art.labels_b < 0).sum())},
            "config": _jsonable(asdict(config)),
            "timings": timings,
        })
    log.info("model: %d links, %d joints, timings %s", len(links), len(art.joints),
             {k: round(v, 1) for k, v in timings.items()})
    return model


def links_from_labels(dense_a, dense_b, labels_a: np.ndarray, labels_b: np.ndarray,
                      transforms) -> list[Link]:
    """The links of a model from its labelled dense points (configuration A's frame).

    Link k holds the points of A labelled k and the points of B labelled k carried back into A
    by the inverse of its transform: together, the link as both configurations saw it (what one
    of them hid, the other may show). ``Link.observed_in`` says which configuration saw each.

    Parameters
    ----------
    dense_a, dense_b : artrecon.dense.DensePoints
    labels_a, labels_b : (len(dense_a),), (len(dense_b),) int
        Link per point (artrecon.assign).
    transforms : sequence of Similarity
        Each link's A -> B transform.
    """
    links = []
    for k, T in enumerate(transforms):
        ia, ib = labels_a == k, labels_b == k
        pts = np.concatenate([dense_a.points[ia], T.inverse().apply(dense_b.points[ib])])
        nrm = np.concatenate([dense_a.normals[ia], dense_b.normals[ib] @ T.rotation])
        col = np.concatenate([dense_a.colors[ia], dense_b.colors[ib]])
        seen = np.concatenate([np.zeros(int(ia.sum()), np.int8), np.ones(int(ib.sum()), np.int8)])
        links.append(Link(points=pts, match_indices=np.full(len(pts), -1), transform_a_to_b=T,
                          colours=col, normals=nrm, name=f"link_{k}", observed_in=seen))
    return links


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)
