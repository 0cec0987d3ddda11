"""The SfM stage's settings (:class:`SfMConfig`, each field with why its default) and the name of
the self-calibration's record in the SfM folder."""

from __future__ import annotations

from dataclasses import dataclass

#: Written into the SfM folder by the self-calibration
#: (:func:`artrecon.sfm.mapping.map_calibrated`): where the focal length came from (EXIF or
#: self-calibrated), its starting value and the converged one.
CALIBRATION_FILE = "calibration.json"


@dataclass(frozen=True)
class SfMConfig:
    """Settings of the SfM stage."""

    max_num_features: int = 4096
    """SIFT features per image (COLMAP default 8192; 4096 halves matching time at 640x480)."""
    max_image_size: int = 1600
    """Longer image side used for extraction; larger photos are downscaled."""
    extractor: str = "opencv"
    """SIFT implementation: ``"opencv"`` (OpenCV's ``SIFT_create``, written into the same COLMAP
    database; see :func:`artrecon.sfm.extract`) or ``"colmap"`` (COLMAP's, on the CPU). Measured
    on a pliers capture (121 images, one core, under load): COLMAP's 140 s against OpenCV's 63 s,
    for 14351 and 13406 triangulated points."""
    opencv_contrast: float = 0.02
    """OpenCV SIFT's contrast threshold (its default 0.04 keeps about 60% of the keypoints of
    COLMAP's peak threshold on the bundled scenes; 0.02 about as many)."""
    first_octave: int = -1
    """SIFT's first octave (COLMAP default -1: the image is upsampled 2x first). 0 extracts ~3x
    faster (measured 0.28 -> 0.09 s per 640x480 image) but finds half the keypoints, and the
    small, flat links (pliers, scissors) already have the fewest cross-configuration matches.
    COLMAP's extractor only: OpenCV's SIFT (the default ``extractor``) always upsamples first
    and has no such setting."""
    region_margin_px: int = 32
    """With camera poses and the object's region (``cameras.json``'s ``region``): features are
    extracted only in the box around the region's projection, widened by this many pixels on
    each side (the region's points outline the object; SIFT needs some image around a keypoint
    for its scale space and descriptor). Measured on pliers A (121 images, 640x480, the survey's
    hull as the region, margin 24): the boxes hold 17% of the image area, and the SfM stage took
    5.4 CPU s instead of 27.3 (extraction 3.0 against 14.9, matching 1.5 against 9.0), with 1642
    points inside the hull's bounding box against 1651 from the whole images. Negative: the
    whole images always. OpenCV's extractor only (``extractor``)."""
    background_features: int = 512
    """With the region's boxes (``region_margin_px``): SIFT features outside the box too, at most
    this many per image, found in the image scaled by ``background_scale``. The base's motion is
    anchored to the table's and room's matches (:mod:`artrecon.link_motions`), and the dense
    stage's disparity ranges come from the sparse points a pair shares: without them a thin,
    flat base's roll lost its anchor. Measured on scissors seed 2 (the CLI with the capture's
    poses on the same images, axis against the truth): whole images 0.111 deg, SfM 25.4 s per
    configuration; the box alone 0.679 deg, 6.1 s; the box and 1024 features at half scale
    0.081 deg, 17.6 s (extraction 8.4 CPU s, matching 6.2); the box and 512 at quarter scale
    0.129 deg, 11.8 s (5.8 and 3.7), the same dense disparity ranges as the whole images'
    (pairs' mean 164 against 166 disparities). 0: none."""
    background_scale: float = 0.25
    """Scale of the image the background features are found in (OpenCV's SIFT doubles it
    first: a quarter is searched at half the image's resolution)."""
    matching: str = "auto"
    """'auto' (with camera poses: :func:`artrecon.sfm.pairs.pose_pairs`; without: sequential
    window + retrieval pairs), 'exhaustive', or 'sequential' (window only)."""
    pose_neighbours: int = 6
    """With camera poses: images matched with each image, those whose optical axes are nearest
    (on the default rings, 10 degrees apart: the neighbours on each side and the nearest views of
    the rings above and below). Measured on pliers A: 8 gave 559 pairs, 13831 points of mean
    track length 11.5; 6 gives 409 pairs (matching about 27% cheaper), 14133 points of 11.0."""
    pose_ba_refinements: int = 2
    """With camera poses: rounds of bundle adjustment (points only, the poses held) with track
    completion, merging and filtering after the triangulation (COLMAP's default 5). Measured on
    pliers A (121 images): 5 rounds 13831 points, reprojection 0.456 px, 8.6 CPU s; 2 rounds
    13839 points, 0.458 px, 5.9 s; 1 round 13903, 0.468 px; none 14144, 0.597 px."""
    pose_verify_min_trials: int = 20
    """With camera poses: fewest RANSAC trials of COLMAP's two-view verification (its default
    100). The images of a pose ring share ~99% inliers, where RANSAC's own stopping rule needs a
    handful; harder pairs still get the trials the rule asks for. Measured on pliers A: 365157
    instead of 365222 inliers, verification about half as long (~10 -> ~5 CPU s)."""
    pose_max_angle_deg: float = 35.0
    """With camera poses: no pair whose optical axes are further apart than this (SIFT matches
    thin out beyond ~30 degrees of viewpoint change)."""
    sequential_window: int = 4
    """Neighbours in file-name order matched with each image."""
    retrieval_neighbours: int = 8
    """Most similar images matched with each image (loop closure, second ring)."""
    retrieval_sample: int = 300
    """Descriptors per image used to score image similarity (cost grows with its square and
    with n^2 image pairs; 300 still ranks ring neighbours correctly)."""
    global_ba_growth: float = 1.1
    """Incremental mapping (no camera poses): a global bundle adjustment runs each time the
    registered images or the points have grown by this factor since the last one (COLMAP's
    ``ba_global_frames_ratio`` and ``ba_global_points_ratio``, default 1.1); between them local
    bundle adjustments keep the newest images' neighbourhoods refined, and mapping ends with a
    global one either way. Larger is faster but kept at COLMAP's 1.1: at 1.3 the photo route
    took 6% less (pliers 117.6-120.6 -> 110.4-113.0 s, truck 132.8 -> 124.6 s, the same
    hinges), but with a wrong focal length given (2x) the layout bent less, and the check that
    blames the intrinsics (``max_layout_error``, 5% of the cameras' spread) lost its margin: the
    hinge fixture's configuration A 7.5% -> 5.5%, and on another process's rendering below 5%,
    so the run ended in the dense stage ("only 0 points agree") instead of naming the
    intrinsics (CI at e3db26d). A larger factor needs that check made independent of it first."""
    min_registered_fraction: float = 0.7
    """Fewer registered images than this share of the set is a failure (views would be missing)."""
    num_threads: int = 1
    """Threads for COLMAP (-1 = all cores). One: COLMAP's geometric verification runs its
    RANSAC per thread, so with several the inlier sets (and every later figure) change from run
    to run (measured: 14051-14056 points of the same images); the reconstruction runs the two
    configurations side by side instead (:func:`artrecon.reconstruct.reconstruct`, ``jobs``)."""
    max_layout_error: float = 0.05
    """When reference poses exist (cameras.json) but SfM ran from the images, the SfM camera
    centres, aligned by a similarity, must match them within this fraction of the cameras' spread
    (a folded ring of cameras is far off; a good model is ~0.1% off)."""
    max_focal_mismatch: float = 0.10
    """Given intrinsics on image folders without reference poses (no cameras.json to check the
    cameras' layout against): refused when a bundle adjustment of a copy of the SfM result with
    the focal length free (:func:`artrecon.sfm.focal_check.supported_focal`) moves it further
    than this fraction from the given one (SfM holds given intrinsics fixed, so a wrong focal
    length only bends the layout, and the dense stage failed minutes later blaming the poses).
    Measured on the hinge fixture (36 views, true f 554.26 px), plain folder A: given 554.26 ->
    554.34 px; given 2 x -> 558.5 px; 1.15 x -> 555.2 px; 0.5 x -> 524.0 px. 10% is about
    twice the worst of those estimates' errors (5.5%, from the half focal length)."""
    min_focal_reprojection_gain: float = 2.0
    """... and freeing it divides the mean reprojection error by at least this: a focal length
    that drifts on weak geometry does not fit the images much better. Same runs: right 0.167 ->
    0.167 px (1.0 x); 2 x 1.30 -> 0.12 px (11 x); 1.15 x 0.96 -> 0.16 px (6.1 x); 0.5 x 1.15 ->
    0.25 px (4.7 x)."""
    max_pose_epipolar_px: float = 0.45
    """Given camera poses (known-pose triangulation) are refused when the images' verified
    two-view matches of either configuration lie further than this (median Sampson distance,
    pixels) from the epipolar lines the poses predict (:func:`artrecon.sfm.pose_agreement`). The
    known-pose path needs poses about as exact as the images: measured with ``python -m sim.evaluate
    pliers --views 18 --use-poses`` (640x480, 60 images per set) and sim.perturb's errors of the
    arm's poses (figures for A / B): exact poses 0.13 / 0.13 px (0.09-0.14 on cabinet, barrett_hand,
    scissors, pliers_panda); good models at 0.39 / 0.36 px (encoder noise 0.02 deg, axis 0.6 deg)
    and 0.50 / 0.51 (1 mm / 0.2 deg mount error, 0.7 deg); wrong axes without any error at
    0.51 / 0.46 (2 mm / 0.4 deg, seed 1: 3.5 deg), 0.89 / 0.79 (encoder 0.05 deg: 3.2 deg) and
    1.32 / 1.39 (5 mm / 1 deg, seed 2: 7.4 deg), while 5 mm / 1 deg gave good axes at seeds 0
    and 1 (2.2 and 1.1 px): from ~0.5 px on, the answer is a coin toss. 0.45 px refuses every
    wrong answer measured and keeps the 0.39 px one (the 1 mm mount error is refused too)."""
    min_pose_triangulated_share: float = 0.8
    """... or when fewer than this share of those matches end in one triangulated 3D point
    (COLMAP keeps a track only within 4 px of every view): a second, coarser sign of the same.
    Same runs: 0.95-0.97 with exact poses and up to 0.5 px; 0.92-0.94 at 0.5-0.9 px; 0.44-0.69
    at 1-2.3 px; below 0.4 beyond (encoder noise 0.1 deg and more, mount errors of 10 mm and
    more)."""
    suspect_pose_epipolar_px: float = 0.3
    """Given poses that pass the check but agree with the images worse than this (median
    epipolar distance, pixels; 2.3 x the 0.13 px of exact poses) are named as the likely cause
    when segmentation or a joint's evidence fails later
    (:func:`artrecon.diagnosis.blame_poses`)."""
