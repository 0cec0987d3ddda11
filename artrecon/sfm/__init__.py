"""Structure from motion per configuration, with pycolmap.

Stage input: one checked image folder (:class:`artrecon.io.ImageSet`), optional intrinsics,
optional camera poses. Stage output: :class:`SfMResult` holding a ``pycolmap.Reconstruction``
(cameras, sparse points with their observing keypoints) written in COLMAP's folder layout
``OUT/sparse/0`` beside ``OUT/database.db`` (SIFT keypoints and descriptors, reused for the matches
across configurations) and ``OUT/colmap.log`` (and ``OUT/calibration.json`` when the focal length
was not given: see :func:`~artrecon.sfm.mapping.map_calibrated`).

Image pairs. Exhaustive matching costs n^2/2 pairs and, on repeated texture, can fold a ring of
cameras onto itself. With camera poses (the arm's forward kinematics) each image is matched with
the images whose optical axes are nearest to its own (:func:`~artrecon.sfm.pairs.pose_pairs`:
the views that overlap, neighbours on a ring and across rings). Without poses we match a union
of (a) a window of neighbours in file-name order (captures are written in order) and (b) retrieval
pairs: for each image the images sharing most mutual nearest neighbours among a sample of its
descriptors (a cheap stand-in for a vocabulary tree; it also closes the loop of a ring).
``matching="exhaustive"`` is available for small sets.

Two modes:

* default, the method's: incremental SfM from the images alone (pose search).
* ``poses`` given (the arm's forward kinematics): the poses are held fixed, points are triangulated
  and refined by bundle adjustment; no pose search. Much faster, and metric. The poses are then
  checked against the images (:func:`pose_agreement`: epipolar distance of the verified
  matches, share that triangulates); poses that disagree, as a camera mount (hand-eye) error or
  encoder errors make them, are refused with a :class:`~artrecon.errors.PoseMismatchError`: wrong
  cameras would give a wrong model without any error.

The package: :mod:`~artrecon.sfm.stage` (:func:`run_sfm`, :class:`SfMResult`) runs the steps
of :mod:`~artrecon.sfm.extraction` (features into the database), :mod:`~artrecon.sfm.pairs`
(which images to match; matching and verification), :mod:`~artrecon.sfm.mapping` (incremental,
self-calibrated second pass, known poses), :mod:`~artrecon.sfm.pose_check` and
:mod:`~artrecon.sfm.focal_check` (given intrinsics against the images); its settings are
:class:`~artrecon.sfm.config.SfMConfig`. The names below are its face (what the other stages,
the harness and the tests use).
"""

from artrecon.sfm.config import SfMConfig
from artrecon.sfm.extraction import extract, read_features
from artrecon.sfm.pairs import select_pairs
from artrecon.sfm.pose_check import check_pose_agreement, pose_agreement
from artrecon.sfm.stage import SfMResult, camera_poses, camera_summary, layout_error, run_sfm

__all__ = [
    "SfMConfig",
    "SfMResult",
    "camera_poses",
    "camera_summary",
    "check_pose_agreement",
    "extract",
    "layout_error",
    "pose_agreement",
    "read_features",
    "run_sfm",
    "select_pairs",
]
