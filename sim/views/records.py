"""The records of a view plan: how the views are laid out (:class:`ViewPlanConfig`), the views
(:class:`View`), the rings chosen (:class:`Ring`) and the plan (:class:`ViewPlan`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The method needs at most about 10 degrees between neighbouring views (issue 3): 36 per ring.
MAX_NEIGHBOUR_ANGLE_DEG = 10.0

#: Fewest views per full ring a capture may ask for (``--views`` of sim.capture and sim.evaluate,
#: :attr:`ViewPlanConfig.views_per_ring`): with fewer, neighbours on a ring are more than 90
#: degrees apart and no two views of the object share enough of it to be matched.
MIN_VIEWS = 4


def views_problem(n_views: int, flag: str = "--views") -> str | None:
    """The message for a views-per-ring value below :data:`MIN_VIEWS` (None when it is fine):
    one wording for every command."""
    if n_views >= MIN_VIEWS:
        return None
    return (f"{flag} must be at least {MIN_VIEWS} (views per full ring; 36 keeps neighbours 10 "
            f"degrees apart), got {n_views}")


#: Views per full ring by default, the one place that says it: neighbours 10 degrees apart (the
#: main job's configuration; ``--views`` of sim.capture and sim.evaluate, and every default that
#: means "the usual capture", read it here).
DEFAULT_VIEWS_PER_RING = 36


@dataclass(frozen=True)
class ViewPlanConfig:
    """How the views are laid out."""

    views_per_ring: int = DEFAULT_VIEWS_PER_RING
    """views on each ring of `elevations_deg` (36 keeps neighbours 10 degrees apart)"""
    elevations_deg: tuple[float, ...] = (20.0, 40.0, 60.0)
    """desired elevations (degrees above the horizontal plane through the object's centre) of the
    full rings"""
    top_elevations_deg: tuple[float, ...] = (70.0,)
    """rings near the top; they get fewer views, as many as keep neighbours as close as on the
    full rings"""
    fill: float = 0.6
    """preferred diameter of the object's bounding sphere as a share of the shorter image side"""
    fill_range: tuple[float, float] = (0.45, 0.75)
    """the band of fills a ring may take when the arm cannot reach it at the preferred one (the
    object still fills a good part of the image and stays sharp and whole in it)"""
    max_elevation_shift_deg: float = 10.0
    """how far a ring may move from its desired elevation when no distance in the band gives a
    ring the arm reaches everywhere"""
    seed: int = 0
    """seeds the azimuth of each ring's first view and the IK restarts"""

    def __post_init__(self):
        problem = views_problem(self.views_per_ring, "views_per_ring (--views)")
        if problem:
            raise ValueError(problem)
        lo, hi = self.fill_range
        if not 0.05 <= lo <= hi <= 1.0:
            raise ValueError(f"fill_range must satisfy 0.05 <= low <= high <= 1, got "
                             f"{self.fill_range}")
        if not lo <= self.fill <= hi:
            raise ValueError(f"fill must lie in fill_range {self.fill_range}, got {self.fill}")
        if not 0.0 <= self.max_elevation_shift_deg <= 30.0:
            raise ValueError(f"max_elevation_shift_deg must lie in [0, 30], got "
                             f"{self.max_elevation_shift_deg}")
        for e in (*self.elevations_deg, *self.top_elevations_deg):
            if not -80.0 <= e <= 85.0:
                raise ValueError(f"ring elevations must lie in [-80, 85] degrees, got {e}")
        if not self.elevations_deg and not self.top_elevations_deg:
            raise ValueError("give at least one ring elevation")


@dataclass
class View:
    """One planned view and, once planned, how the arm reaches it."""

    index: int
    """position in the plan (capture order)"""
    ring: int
    """ring number, in the order of the config's elevations then top elevations"""
    azimuth: float
    """radians about world z from world x, seen from the object centre"""
    elevation: float
    """radians above the horizontal plane through the object centre"""
    distance: float
    """camera centre to object centre (m)"""
    T_world_camera: np.ndarray
    """(4, 4) target camera pose, OpenCV convention, looking at the object centre"""
    q: np.ndarray | None = None
    """(n,) joint angles (rail first) that reach it, None if unreachable"""
    roll_deg: float = 0.0
    """image roll used to reach it"""
    reason: str = ""
    """why the view is unreachable (empty when reachable)"""

    @property
    def reachable(self) -> bool:
        return self.q is not None


@dataclass(frozen=True)
class Ring:
    """One ring of views as chosen by :func:`plan_capture`."""

    index: int
    """ring number"""
    desired_elevation: float
    """the configuration's elevation for it (rad)"""
    elevation: float
    """the elevation chosen (rad)"""
    distance: float
    """camera centre to object centre (m)"""
    fill: float
    """the object's bounding-sphere diameter as a share of the shorter image side"""
    n_views: int
    """views on the ring"""
    azimuth0: float
    """azimuth of its first view before ordering (rad)"""
    top: bool = False
    """a top ring (fewer views)"""
    candidates_tried: int = 0
    """(elevation, distance) pairs probed before this one was chosen"""


@dataclass
class ViewPlan:
    """The planned views of one capture."""

    centre: np.ndarray
    """(3,) the object's bounding-sphere centre, every camera looks at it"""
    radius: float
    """bounding-sphere radius (m)"""
    rings: list[Ring] = field(default_factory=list)
    """the rings chosen, in capture order"""
    views: list[View] = field(default_factory=list)

    @property
    def reachable(self) -> list[View]:
        return [v for v in self.views if v.reachable]

    @property
    def unreachable(self) -> list[View]:
        return [v for v in self.views if not v.reachable]
