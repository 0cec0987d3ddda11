"""Tunables of a capture, and how a user changes them.

:class:`CaptureConfig`, one frozen dataclass, holds the tunables besides the view plan: read by
the arm's motion (:class:`~sim.capture.arm.Arm`), the image set's check that the object stays put
(:func:`~sim.capture.image_set.capture`) and the fresh view
(:func:`~sim.capture.fresh.capture_fresh_view`). The view plan's own tunables are fields of
:class:`sim.views.ViewPlanConfig` (they key the plan cache). Each field says why it has its value.

``python -m sim.capture`` and ``python -m sim.evaluate`` change them with ``--set
capture.FIELD=VALUE`` (a field of CaptureConfig) and ``--set views.FIELD=VALUE`` (of
ViewPlanConfig; a list field takes comma-separated values, ``views.elevations_deg=20,40,60``):
:func:`capture_settings` checks each against its row of :data:`RANGES` with
artrecon's own settings code (:func:`artrecon.settings.apply_settings`), so that a value the
capture cannot run with is refused at once, naming the valid range. The ranges bound what the
code can run with and what means something; the defaults are what the method is measured with.

This module is not part of the :mod:`sim.capture` package (which re-exports CaptureConfig): every
module of that package loads pyrender, which needs an EGL library, through the package, and
:mod:`sim.evaluate` holds these settings in its EvalConfig and loads without one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from artrecon.errors import InputError
from artrecon.settings import ListOf, Range, apply_settings
from sim.views import ELEVATION_LIMITS_DEG, ViewPlanConfig

_OPEN = dict(low_open=True)


@dataclass(frozen=True)
class CaptureConfig:
    """How the arm moves between views, how still the object must stay, where the fresh view
    lies."""

    move_speed: float = 1.0
    """peak joint-space speed (rad/s) of the commanded motion between views: a minimum-jerk
    profile along the straight joint-space line, with computed-torque feed-forward (see
    :class:`~sim.capture.arm.Arm`); the fastest joint of a move reaches it at mid-move"""
    settle_speed: float = 1e-3
    """the arm has settled at a view when its joint speeds are below this (rad/s) ..."""
    settle_max_time: float = 2.0
    """... or after this much simulated time (s), whichever is first"""
    object_drift_tol: float = 1e-4
    """the object may not move while the arm works around it: its joints must stay within
    this (rad or m) of the configuration; 0.1 mrad / 0.1 mm is below anything a reconstruction
    resolves, and the joint holds keep loaded hinges within 1e-5 of it
    (sim.scene.HOLD_SOLREF)"""
    fresh_elevation_deg: float = 30.0
    """elevation (degrees) of the fresh view: between the first two capture rings (20 and 40
    degrees by default), so no image of a set was taken from there ..."""
    fresh_azimuth_offsets_deg: tuple[float, ...] = (5.0, 15.0, -5.0, -15.0, 25.0, -25.0, 35.0,
                                                    -35.0)
    """... and half a capture step (10 degrees at 36 views per ring) off the arm's current
    azimuth; the further offsets (degrees) are tried in this order when that one is out of
    reach"""

    def __post_init__(self):
        for name in ("move_speed", "settle_speed", "settle_max_time", "object_drift_tol"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"CaptureConfig.{name} must be a positive number, got {value}")
        low, high = ELEVATION_LIMITS_DEG
        if not low <= self.fresh_elevation_deg <= high:
            raise ValueError(f"CaptureConfig.fresh_elevation_deg must lie in [{low:g}, "
                             f"{high:g}] degrees, got {self.fresh_elevation_deg}")
        if not self.fresh_azimuth_offsets_deg:
            raise ValueError("CaptureConfig.fresh_azimuth_offsets_deg needs at least one offset")


#: One row per field that ``--set`` changes: ``capture.FIELD`` (:class:`CaptureConfig`) and
#: ``views.FIELD`` (:class:`sim.views.ViewPlanConfig`); a list field's row (:class:`ListOf`)
#: bounds each of its values (and their number where the field needs one), the field's own
#: check the rest (fill within fill_range, the first roll 0).
RANGES: dict[str, Range | ListOf] = {
    # --- capture (CaptureConfig)
    "capture.move_speed": Range(0, 10, "rad/s, the fastest joint at mid-move", **_OPEN),
    "capture.settle_speed": Range(0, 1, "rad/s", **_OPEN),
    "capture.settle_max_time": Range(0, 60, "simulated seconds", **_OPEN),
    "capture.object_drift_tol": Range(0, 0.01, "rad or m; 1 cm moves the object itself",
                                      **_OPEN),
    "capture.fresh_elevation_deg": Range(*ELEVATION_LIMITS_DEG, "degrees above the object's "
                                         "centre"),
    "capture.fresh_azimuth_offsets_deg": ListOf(Range(-180, 180, "degrees off the arm's "
                                                      "azimuth, tried in this order")),
    # --- views (sim.views.ViewPlanConfig)
    "views.elevations_deg": ListOf(Range(*ELEVATION_LIMITS_DEG, "degrees above the object's "
                                         "centre, a full ring each")),
    "views.top_elevations_deg": ListOf(Range(*ELEVATION_LIMITS_DEG, "degrees above the "
                                             "object's centre, a top ring each"),
                                       may_be_empty=True),
    "views.fill_range": ListOf(Range(0.05, 1, "a share of the shorter image side: low, high"),
                               length=2),
    "views.roll_candidates_deg": ListOf(Range(-180, 180, "degrees about the optical axis, "
                                              "tried in this order, the first 0")),
    "views.fill": Range(0.05, 1, "a share of the shorter image side, within fill_range"),
    "views.max_elevation_shift_deg": Range(0, 30, "degrees"),
    "views.fill_step": Range(0, 1, "a share of the shorter image side", **_OPEN),
    "views.elevation_step_deg": Range(0, 30, "degrees", **_OPEN),
    "views.probe_views": Range(1, 360, "views of a candidate ring"),
    "views.probe_ik_restarts": Range(0, 100, "IK restarts"),
    "views.ik_restarts": Range(0, 100, "IK restarts"),
    "views.rolled_ik_restarts": Range(0, 100, "IK restarts"),
    "views.clearance_m": Range(0, 0.1, "metres", **_OPEN),
    "views.self_clearance_m": Range(0, 0.1, "metres"),
    "views.path_check_step": Range(0, 0.5, "radians", **_OPEN),
    "views.min_ring_distance": Range(0, 2, "metres from the object's centre", **_OPEN),
}

#: Fields that ``--set`` does not change, and why.
NOT_SET = {
    "views.views_per_ring": "views per ring are set by --views",
    "views.seed": "the seed is set by --seed",
}


#: The ``--set`` option's help, the same in both commands.
SET_HELP = ("change one capture setting (repeatable): capture.FIELD=VALUE, a field of "
            "sim.capture.CaptureConfig (the arm's motion, the object's drift, the fresh view), "
            "or views.FIELD=VALUE, a field of sim.views.ViewPlanConfig (IK restarts, clearance, "
            "the ring search), each within its range in sim.capture_config.RANGES, e.g. "
            "views.clearance_m=0.02; a list as comma-separated values, e.g. "
            "views.elevations_deg=20,40,60")
#: The example a malformed ``--set`` item is shown.
SET_EXAMPLE = "views.clearance_m=0.02"


@dataclass(frozen=True)
class CaptureSettings:
    """Every tunable of a capture: the arm's motion and the fresh view, and the view plan's."""

    capture: CaptureConfig = field(default_factory=CaptureConfig)
    """the arm's motion between views, the object's drift, the fresh view"""
    views: ViewPlanConfig = field(default_factory=ViewPlanConfig)
    """the view plan (its views per ring and seed are the command's --views and --seed)"""

    def changed(self) -> dict:
        """``{"capture.FIELD": value, "views.FIELD": value}`` of the fields off their defaults
        (``{}`` at the defaults): the settings as a user gives them, for records and cache
        keys."""
        out = {}
        for part, default in (("capture", CaptureConfig()), ("views", ViewPlanConfig())):
            config = getattr(self, part)
            out.update({f"{part}.{f.name}": getattr(config, f.name) for f in fields(config)
                        if getattr(config, f.name) != getattr(default, f.name)})
        return out


def capture_settings(settings: Mapping[str, float | int | bool | str]) -> CaptureSettings:
    """:class:`CaptureSettings` with ``settings`` (``{"capture.FIELD": value, "views.FIELD":
    value}``) applied, each checked against its row of :data:`RANGES`.

    Raises
    ------
    InputError
        An unknown part or field, a field ``--set`` does not change (:data:`NOT_SET`), or a
        value of the wrong kind, not finite or out of range; the message gives the valid range.
    """
    for key in settings:
        if key in NOT_SET:
            raise InputError(f"setting {key!r} cannot be set with --set: {NOT_SET[key]}")
    return apply_settings(CaptureSettings(), dict(settings), ranges=RANGES, ordered=())
