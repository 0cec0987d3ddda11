"""Errors raised by artrecon. Each message says what was wrong, where, and what to do."""


class ArtreconError(Exception):
    """Base class of every error the reconstruction raises on purpose."""


class InputError(ArtreconError, ValueError):
    """The input (folder, image, array) is missing, unreadable or malformed."""


class DegenerateError(ArtreconError):
    """The data cannot determine the answer (too few points, collinear points, no motion...)."""


class ReconstructionError(ArtreconError):
    """A stage could not do its job (SfM failed, too few matches, no link found...)."""


class NoMotionError(DegenerateError):
    """The two configurations are identical: no link moved, so no joint can be observed."""


class SingleBodyError(DegenerateError):
    """Everything moved as one rigid body (one link found): no joint can be observed."""


class WeakEvidenceError(ReconstructionError):
    """The matches do not determine a joint well enough (too few inliers, a motion below the
    noise, an ill-conditioned axis): refused rather than answered wrongly.

    Attributes
    ----------
    records : list of dict
        The confidence record of every joint (artrecon.confidence), refused or not.
    """

    def __init__(self, message: str, records: list | None = None):
        super().__init__(message)
        self.records = list(records or [])


class MismatchError(ReconstructionError):
    """Two measurements that must agree do not; ``agreement`` holds the figures."""

    def __init__(self, message: str, agreement: dict | None = None):
        super().__init__(message)
        self.agreement = dict(agreement or {})


class PoseMismatchError(MismatchError):
    """The given camera poses (e.g. the arm's forward kinematics) do not agree with the images:
    the images' verified feature matches contradict the epipolar geometry the poses predict, and
    few of them triangulate. Refused rather than reconstructed from wrong cameras (a wrong model).

    Attributes
    ----------
    agreement : dict
        The measured figures (:func:`artrecon.sfm.pose_agreement`).
    """


class RegistrationMismatchError(MismatchError):
    """Two registrations of the model into the robot's frame (camera centres against the arm's
    camera positions; PnP of a fresh image with the hand-eye calibration) disagree by more than a
    grasp tolerates: the arm's camera positions are off (a camera mount error on the wrist, arm
    encoder errors). Refused rather than handing the arm axes in a wrong place.

    Attributes
    ----------
    agreement : dict
        The measured figures (:func:`artrecon.register.agreement.registration_agreement`).
    """
