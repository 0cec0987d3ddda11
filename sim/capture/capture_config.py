"""Tunables of a capture besides its view plan: one frozen dataclass, :class:`CaptureConfig`, read
by the arm's motion (:class:`~sim.capture.arm.Arm`), the image set's check that the object stays
put (:func:`~sim.capture.image_set.capture`) and the fresh view
(:func:`~sim.capture.fresh.capture_fresh_view`). The view plan's own tunables are fields of
:class:`sim.views.ViewPlanConfig` (they key the plan cache). Each field says why it has its
value."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
        if not -80.0 <= self.fresh_elevation_deg <= 85.0:
            raise ValueError(f"CaptureConfig.fresh_elevation_deg must lie in [-80, 85] degrees, "
                             f"got {self.fresh_elevation_deg}")
        if not self.fresh_azimuth_offsets_deg:
            raise ValueError("CaptureConfig.fresh_azimuth_offsets_deg needs at least one offset")
