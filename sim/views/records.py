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

#: Elevations a view may take, degrees above the object's centre (low, high): the capture rings
#: (:attr:`ViewPlanConfig.elevations_deg`, and where the planner may shift them) and the fresh
#: view (sim.capture_config).
ELEVATION_LIMITS_DEG = (-80.0, 85.0)


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
    """How the views are laid out, and the tunables of how the planner reaches them: all of a
    view plan's settings, so that the plan cache's key (:func:`sim.capture.plan_inputs`, which
    holds every field) changes with any of them."""

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

    # ----- the search for each ring (sim.views.planner): not the layout, how it is reached
    fill_step: float = 0.05
    """step (share of the shorter image side) between a ring's candidate fills in
    `fill_range`: 0.05 is 2-4 cm of camera distance for the bundled objects"""
    elevation_step_deg: float = 2.5
    """step (degrees) between a ring's candidate elevations within
    `max_elevation_shift_deg`: a quarter of the 10 degree view spacing"""
    probe_views: int = 6
    """views of a candidate ring probed (evenly spread in azimuth) before it is solved in
    full: enough to meet the part of a ring that is out of reach, few enough that a hopeless
    candidate costs little"""
    probe_ik_restarts: int = 2
    """random IK restarts per probed view. Most rings the arm reaches are reached from the
    neighbouring view's solution at once, so the probe spends little on hopeless rings; the
    price is that a ring at the very edge of the workspace may fail its probe and give way to
    the next candidate (another distance in the band), never that an unreachable view is
    planned"""

    # ----- reaching one view (sim.views.solve, sim.views.rings; also the fresh view's)
    ik_restarts: int = 8
    """random IK restarts for a view upright (:func:`sim.robot.solve_view_ik`)"""
    rolled_ik_restarts: int = 2
    """random IK restarts for each rolled fallback of a view (at most `ik_restarts`): a roll
    is tried only when the view failed upright, from the previous view's solution"""
    roll_candidates_deg: tuple[float, ...] = (0.0, 90.0, -90.0, 180.0, 45.0, -45.0, 135.0,
                                              -135.0)
    """image rolls (rotation about the optical axis, degrees) tried in this order; the first
    must be 0 (upright). Any roll shows the same scene, so it is a free choice of the planner"""
    clearance_m: float = 0.01
    """clearance (m) the planned arm keeps from everything that is not the robot (object,
    table, floor) at every view and at every checked step of the moves between views. The
    servos follow the planned joint-space line within a few millimetres (sim.capture feeds
    each one its own lag forward), but a plan that merely avoided contact could pass a few
    millimetres from a thin part: scraper_truck's configuration B had a move 9.8 mm from the
    blade that the rail's lag (0.3 s behind the wrist) turned into a contact, and the capture
    failed. 1 cm is also a fifth of the 5 cm a joint step of `path_check_step` moves the
    wrist at most, the margin between two checked configurations"""
    self_clearance_m: float = 0.003
    """clearance (m) the planned arm's links keep from each other and from the rest of the robot
    (at every view and checked step), less than ``clearance_m``: parts of one arm pass closer by
    design. With none, the closed-form IK put a ring's views of cabinet (seed 1) 0.4-0.9 mm
    from a contact of the wrist's link 4 with link 6 (the wrist bent to -91 deg), and the
    servos' lag along the move to view 7 made it one: the capture failed, as drawer's (seed 2)
    and cabinet_door_only's (seed 1) did"""
    path_check_step: float = 0.02
    """largest joint step (rad) between the configurations checked for contacts along the
    straight joint-space move from one view to the next (sim.capture drives the servos along
    that line): 0.02 rad moves a point 1 m from the joint by 2 cm, less than the links'
    thickness"""
    min_ring_distance: float = 0.25
    """smallest camera distance (m) from the object's centre: the wrist camera's near clipping
    distance (sim.render.ZNEAR, 0.15 m) plus room for the gripper, whatever the object's
    size"""

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
        low, high = ELEVATION_LIMITS_DEG
        for e in (*self.elevations_deg, *self.top_elevations_deg):
            if not low <= e <= high:
                raise ValueError(f"ring elevations must lie in [{low:g}, {high:g}] degrees, "
                                 f"got {e}")
        if not self.elevations_deg and not self.top_elevations_deg:
            raise ValueError("give at least one ring elevation")
        for name in ("fill_step", "elevation_step_deg", "clearance_m", "path_check_step",
                     "min_ring_distance"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"ViewPlanConfig.{name} must be a positive number, got {value}")
        if not (np.isfinite(self.self_clearance_m)
                and 0.0 <= self.self_clearance_m <= self.clearance_m):
            raise ValueError(f"ViewPlanConfig.self_clearance_m must lie in [0, clearance_m = "
                             f"{self.clearance_m}], got {self.self_clearance_m}")
        for name, least in (("probe_views", 1), ("probe_ik_restarts", 0), ("ik_restarts", 0),
                            ("rolled_ik_restarts", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < least:
                raise ValueError(f"ViewPlanConfig.{name} must be a whole number of at least "
                                 f"{least}, got {value!r}")
        rolls = self.roll_candidates_deg
        if not rolls or rolls[0] != 0.0:
            raise ValueError(f"ViewPlanConfig.roll_candidates_deg must start with 0 (the view "
                             f"upright), got {rolls}")


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
    """(3,) the centre of the object's bounding sphere as the survey found it
    (:func:`sim.views.survey.survey_object`); every camera looks at it"""
    radius: float
    """that sphere's radius (m)"""
    rings: list[Ring] = field(default_factory=list)
    """the rings chosen, in capture order"""
    views: list[View] = field(default_factory=list)
    survey: dict | None = None
    """what the survey found (:meth:`sim.views.survey.Survey.to_json`)"""

    @property
    def reachable(self) -> list[View]:
        return [v for v in self.views if v.reachable]

    @property
    def unreachable(self) -> list[View]:
        return [v for v in self.views if not v.reachable]
