"""Registration: metric scale and the robot frame of a reconstructed model.

The reconstruction lives in the frame of configuration A's cameras, in its units (arbitrary when
SfM ran from the images alone). The arm needs it in its own frame (the "robot" frame: the frame
the arm's forward kinematics report poses in), in metres. Two independent routes, which can check
each other on the same data:

(a) :mod:`~artrecon.register.centres`: the camera centres of configuration A against the arm's
    camera positions from forward kinematics (the paper: "the known positions of the end effector
    can be compared with the estimated camera positions to determine the overall scale");
(b) :mod:`~artrecon.register.pnp` with :mod:`~artrecon.register.hand_eye`, the paper's route: a
    fresh image localised against the model by SIFT matches and PnP, turned into model-to-robot
    by the flange pose and the camera's mount on the flange (hand-eye calibration, estimated from
    the capture together with the model's scale).

:mod:`~artrecon.register.stage` is the stage (``artrecon register``): a reconstruction folder in,
the registered model and a report out. :mod:`~artrecon.register.apply` compares registrations and
applies one to a model.
"""

from artrecon.register.apply import (
    RegistrationComparison,
    apply_registration,
    compare_registrations,
)
from artrecon.register.centres import (
    CentreRegistration,
    metric_scale_from_length,
    register_camera_centres,
)
from artrecon.register.hand_eye import HandEyeResult, calibrate_hand_eye
from artrecon.register.pnp import (
    PnPResult,
    landmarks_from_tracks,
    localize_image,
    match_descriptors,
    register_by_pnp,
    sift_features,
)
from artrecon.register.stage import (
    FreshImage,
    RegisterConfig,
    Registration,
    read_fresh_pose,
    read_pose_file,
    register,
    true_registration_error,
)

__all__ = [
    "CentreRegistration",
    "FreshImage",
    "HandEyeResult",
    "PnPResult",
    "RegisterConfig",
    "Registration",
    "RegistrationComparison",
    "apply_registration",
    "calibrate_hand_eye",
    "compare_registrations",
    "landmarks_from_tracks",
    "localize_image",
    "match_descriptors",
    "metric_scale_from_length",
    "read_fresh_pose",
    "read_pose_file",
    "register",
    "register_by_pnp",
    "register_camera_centres",
    "sift_features",
    "true_registration_error",
]
