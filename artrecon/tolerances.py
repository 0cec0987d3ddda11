"""Every threshold of the geometry core (procrustes, segment, joints), in one place, each with why.

Lengths are *relative to the scene size*: SfM reconstructions have an arbitrary scale, so an
absolute threshold in model units means nothing. The scene size is `scene_size(points)`, the median
distance of the points to their coordinate-wise median (robust to outlier matches, unlike the
bounding-box diagonal). The configs in `segment.py` and `joints.py` take their defaults from here.
"""

from __future__ import annotations

import numpy as np

# --- Procrustes -------------------------------------------------------------------------------

#: A point set whose second singular value (of the centred coordinates) is below this fraction of
#: the first is treated as collinear: its rotation about the line is undetermined. 1e-9 is far
#: above float64 round-off (1e-16) on any reasonable cloud, yet far below any real 2D spread.
COLLINEAR_RATIO = 1e-9

# --- Segmentation (sequential RANSAC) ---------------------------------------------------------

#: Inlier distance (in configuration B, relative to B's scene size). A match residual has
#: sqrt(2) sigma per axis (noise in both models), so its norm is below 4.03 x 1.41 sigma = 5.7 sigma
#: for 99.9% of true matches: 2% covers point noise up to 0.35% of the scene size, typical of
#: dense SfM. Raise it (about 6 x relative noise) for noisier reconstructions.
INLIER_THRESHOLD = 0.02

#: After refinement, the inlier distance of a link shrinks to this many times the median inlier
#: residual (never above INLIER_THRESHOLD). For 3D Gaussian noise the residual norm follows a
#: chi(3) law: median 1.54 sigma, so 3.5 x median = 5.4 sigma keeps 99.99% of true inliers while
#: dropping outlier matches that landed by chance inside the coarse threshold.
ADAPTIVE_THRESHOLD_FACTOR = 3.5

#: Floor of the adaptive threshold (relative to scene size), so noise-free data (residuals ~1e-16)
#: does not get a threshold of zero. Matches closer than this are inliers by any standard.
ADAPTIVE_THRESHOLD_FLOOR = 1e-7

#: A link needs at least this many matches...
MIN_LINK_POINTS = 12
#: ...and at least this fraction of all matches. Smaller consensus sets are spurious (outlier
#: matches that agree by chance) or too small to give a usable transform; their matches become -1.
MIN_LINK_FRACTION = 0.02

#: RANSAC confidence that the best link of each round was sampled at least once by an all-inlier
#: triplet; sets the adaptive number of hypotheses N = log(1 - p) / log(1 - w^3).
RANSAC_CONFIDENCE = 0.999

#: Hard cap on hypotheses per round. The last round (no link left) runs to this cap, so it bounds
#: the cost; 5000 finds, at 99.9% confidence, a link holding 11% of the remaining matches.
MAX_HYPOTHESES = 5000

#: Floor on hypotheses per round, so a lucky early triplet cannot end the search too soon.
MIN_HYPOTHESES = 100

#: A sampled triplet whose triangle area is below (this x scene size)^2 is degenerate (nearly
#: collinear points give an ill-determined rotation) and is not scored.
MIN_TRIPLET_SPREAD = 0.05

#: Hypotheses are scored on a random subset of at most this many matches (exact counts are then
#: recomputed on all matches for the best one). 4096 estimates an inlier ratio to +-0.8%.
SCORE_SUBSET = 4096

#: Size of the preliminary test: each hypothesis is first scored on this many matches and fully
#: scored only if its inlier count there reaches half of what the best hypothesis so far (or the
#: smallest acceptable link) would give. A link with inlier ratio w gives 256 w +- sqrt(256 w)
#: probe inliers, so for w >= 5% a true link is dropped with probability < 1e-3 per hypothesis,
#: while the bulk of bad hypotheses (about 0 inliers) costs 16x less to reject.
PROBE_SIZE = 256

#: Numbers of (hypothesis x match) residuals evaluated at once; bounds memory (x 3 x 8 bytes).
SCORE_CHUNK = 1_000_000

# --- Joints -----------------------------------------------------------------------------------

#: Relative rotation angle above which a joint is revolute, below which prismatic. A user moves a
#: joint by tens of degrees; the rotation of a link fitted to >= 12 matches with noise of 1% of its
#: size is wrong by well under 1 degree; 4 degrees sits between with margin on both sides.
REVOLUTE_MIN_ANGLE = np.deg2rad(4.0)

#: Two links are adjacent when their closest points (configuration A) are nearer than this
#: fraction of the scene size. Links of an articulated object touch; SfM points are sparse near
#: the joint, so the gap is allowed to be generous.
ADJACENCY_DISTANCE = 0.5

#: The gap between two links is the k-th smallest nearest-neighbour distance, not the smallest:
#: one or two matches wrongly assigned to a link (possible when two links move almost alike) must
#: not make far-apart links look adjacent.
ADJACENCY_ROBUST_K = 3

#: For many points (a link's dense points) the k above is this share of them instead, when larger:
#: a few dozen mislabelled points of 20000 must not bridge two links either.
ADJACENCY_ROBUST_SHARE = 0.002

#: Weight of the "is this a single joint" misfit in the kinematic-tree edge cost (see
#: joints.single_joint_misfit): a pair whose relative motion is a screw or a rotation+slide is not
#: joined directly when a cleaner pair exists.
MISFIT_WEIGHT = 4.0

#: Relative motion smaller than this (displacement of the moving points, relative to scene size)
#: and rotation below REVOLUTE_MIN_ANGLE means "no motion between the configurations".
NO_MOTION_DISPLACEMENT = 1e-3


def scene_size(points: np.ndarray) -> float:
    """Robust size of a point cloud: median distance of the points to their coordinate-wise median.

    Parameters
    ----------
    points : (n, 3) float

    Returns
    -------
    size : float
        In the units of `points`; 0.0 when all points coincide.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError(f"points must have shape (n, 3) with n >= 1, got {points.shape}")
    centre = np.median(points, axis=0)
    return float(np.median(np.linalg.norm(points - centre, axis=1)))
