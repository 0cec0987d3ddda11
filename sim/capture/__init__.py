"""Eye-in-hand capture: the arm photographs the object from all sides.

``python -m sim.capture SCENE --config a|b --out DIR [--views N] [--seed S] [--set
capture.FIELD=VALUE] [--set views.FIELD=VALUE]`` (the tunables: :mod:`sim.capture_config`) writes
one image set::

    DIR/images/000.png ...        what the wrist camera saw (RGB)
    DIR/cameras.json              intrinsics K, size, per image the arm's joint angles, the
                                  camera and the flange pose from the arm's forward kinematics
                                  (what a real robot knows); this and images/ are what artrecon
                                  reads
    DIR/capture.json              the plan: views planned, captured, unreachable and why
    DIR/ground_truth/             scoring only, never read by artrecon:
        poses.json                true camera poses (MuJoCo), FK error, object joint values, object
                                  link poses, label legend, depth scale
        depth/000.png             uint16 depth along the optical axis, 1 unit = 0.1 mm, 0 = none
        labels/000.png            uint8 label: object link index, 253 arm, 254 stage, 255 nothing

Rooms: :mod:`~sim.capture.image_set` (:func:`capture`, one image set),
:mod:`~sim.capture.fresh` (:func:`capture_fresh_view`, one more image for registration),
:mod:`~sim.capture.plan` (the view plan and its cache), :mod:`~sim.capture.arm` (the arm's motion
in physics), :mod:`~sim.capture.files` (the PNGs, label codes and the output folder),
:mod:`~sim.capture.rig` (the held scene, the arm and its camera),
:mod:`~sim.capture.cli`. The tunables of the arm's motion, the object's drift and the fresh view
are :class:`CaptureConfig`, in :mod:`sim.capture_config` (outside this package, so that what
holds them loads without pyrender; the view plan's are in :class:`sim.views.ViewPlanConfig`).
"""

from sim.capture.arm import min_jerk, servo_gains
from sim.capture.cli import main
from sim.capture.files import (
    DEPTH_PNG_SCALE,
    LABEL_PNG_ARM,
    LABEL_PNG_BACKGROUND,
    LABEL_PNG_STAGE,
    read_depth_png,
    read_labels_png,
)
from sim.capture.fresh import FreshView, capture_fresh_view
from sim.capture.image_set import MIN_CAPTURED_VIEWS, CaptureResult, capture
from sim.capture.plan import plan_inputs, plan_sources, plan_views
from sim.capture.rig import CONFIGS, CaptureError
from sim.capture_config import CaptureConfig

__all__ = [
    "CONFIGS", "DEPTH_PNG_SCALE", "LABEL_PNG_ARM", "LABEL_PNG_BACKGROUND", "LABEL_PNG_STAGE",
    "MIN_CAPTURED_VIEWS", "CaptureConfig", "CaptureError", "CaptureResult", "FreshView", "capture",
    "capture_fresh_view", "main", "min_jerk", "plan_inputs", "plan_sources", "plan_views",
    "read_depth_png", "read_labels_png", "servo_gains",
]
