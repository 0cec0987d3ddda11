"""Settings of one evaluation run (:class:`EvalConfig`), its stage names and its error."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from sim import perturb
from sim.capture_config import CaptureSettings

# the capture's default and fewest views per full ring
from sim.views import DEFAULT_VIEWS_PER_RING, MIN_VIEWS, ViewPlanConfig

#: Where the cameras can come from (:attr:`EvalConfig.poses`).
POSE_SOURCES = ("fk", "images")
__all__ = ["MIN_VIEWS", "POSE_SOURCES", "STAGES", "EvalConfig", "StageError"]

#: Stage names of ``timings_s``, in pipeline order.
STAGES = ("capture_a", "capture_b", "sfm", "dense", "matching", "segmentation_joints",
          "assign_points", "registration", "manipulation", "scoring")


@dataclass(frozen=True)
class EvalConfig:
    """Settings of one evaluation run."""

    views: int = DEFAULT_VIEWS_PER_RING
    """views per full capture ring (sim.capture n_views)"""
    seed: int = 0
    """seed of the capture, reconstruction, registration, manipulation and surface samples"""
    poses: str = "fk"
    """where the cameras come from: ``"fk"`` (default) the arm's forward-kinematics camera
    poses of ``cameras.json``, held fixed, points triangulated, the poses checked against the
    images (a robot knows where its camera is: artrecon.sfm.check_pose_agreement refuses poses
    that disagree); ``"images"`` SfM from the images alone (the photo route: incremental
    mapping, registered afterwards by the camera centres)"""

    def __post_init__(self) -> None:
        if self.poses not in POSE_SOURCES:
            raise ValueError(f"EvalConfig.poses must be one of {POSE_SOURCES}, got {self.poses!r}")
        if self.views < MIN_VIEWS:
            raise ValueError(f"EvalConfig.views must be at least {MIN_VIEWS}, got {self.views}")
        plan = self.capture_settings.views
        if (plan.views_per_ring, plan.seed) != (ViewPlanConfig().views_per_ring,
                                                ViewPlanConfig().seed):
            raise ValueError("EvalConfig.capture_settings.views: its views per ring and seed "
                             "are EvalConfig.views and EvalConfig.seed; leave them at their "
                             "defaults")
    manipulate: bool = True
    """run the manipulation stage"""
    progress: bool = True
    """tqdm progress bars"""
    parallel_capture: bool = True
    """a second process for the scene (:func:`sim.evaluate.stages.second_process`): it captures
    and reconstructs configuration B while this one does A (each chain keeps one core busy:
    planning, physics, rendering, features, dense stereo), then moves every other joint of the
    model while this one scores; the images, models and figures are the same either way"""
    perturb: perturb.Perturbation = field(default_factory=perturb.Perturbation)
    """perturbations of a robustness run (sim.perturb; default none)"""
    capture_settings: CaptureSettings = field(default_factory=CaptureSettings)
    """the captures' and the fresh view's tunables (sim.capture_config: the arm's motion, the
    object's drift, the fresh view, the view plan's tunables; ``--set capture.FIELD=VALUE``,
    ``--set views.FIELD=VALUE``); the views per ring and the seed are :attr:`views` and
    :attr:`seed`"""

    def view_plan(self) -> ViewPlanConfig:
        """The view plan of the captures and of the fresh view: :attr:`capture_settings`'
        with :attr:`views` per ring and :attr:`seed`."""
        return replace(self.capture_settings.views, views_per_ring=self.views, seed=self.seed)


class StageError(RuntimeError):
    """A stage of one scene's evaluation failed; ``stage`` names it."""

    def __init__(self, stage: str, message: str):
        super().__init__(f"{stage}: {message}")
        self.stage = stage
        self.message = message


