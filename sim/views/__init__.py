"""Viewpoint planning for eye-in-hand capture: rings of views around the object, reached by the arm.

Rooms: :mod:`~sim.views.planner` (:func:`plan_capture`: each ring's distance and elevation
chosen so that the arm reaches all of it), :mod:`~sim.views.rings` (the object's bounding sphere,
ring distances and views, the rail's order), :mod:`~sim.views.solve` (IK and the moves between
views), :mod:`~sim.views.survey` (where the object is, from the arm's photographs of the
table), :mod:`~sim.views.clearance` (what the arm comes close to), :mod:`~sim.views.known`
(the cell as the robot knows it, where every check of the plan runs), :mod:`~sim.views.records`
(:class:`ViewPlanConfig`, :class:`View`, :class:`Ring`, :class:`ViewPlan`) and
:mod:`~sim.views.plan_file` (a plan as JSON). Every tunable of the planner (IK restarts, the
clearance, the search's steps) is a field of :class:`ViewPlanConfig`, so the plan cache's key
holds it.
"""

from sim.views.clearance import (
    ClearanceCheck,
    arm_collisions,
    arm_link_bodies,
    clearance_violations,
    robot_bodies,
)
from sim.views.known import KnownCell, hull_vertices, object_contacts
from sim.views.plan_file import PLAN_FORMAT, plan_from_json, plan_to_json
from sim.views.planner import candidates, plan_capture
from sim.views.records import (
    DEFAULT_VIEWS_PER_RING,
    ELEVATION_LIMITS_DEG,
    MAX_NEIGHBOUR_ANGLE_DEG,
    MIN_VIEWS,
    Ring,
    View,
    ViewPlan,
    ViewPlanConfig,
    views_problem,
)
from sim.views.rings import (
    fill_at_distance,
    object_bodies,
    object_bounding_sphere,
    order_for_rail,
    plan_views,
    ring_distance,
    ring_phases,
    ring_size,
    ring_sizes,
    ring_views,
)
from sim.views.solve import check_paths, rolled, solve_views
from sim.views.survey import Survey, SurveyConfig, SurveyError, survey_object

__all__ = [
    "DEFAULT_VIEWS_PER_RING", "ELEVATION_LIMITS_DEG", "MAX_NEIGHBOUR_ANGLE_DEG", "MIN_VIEWS",
    "PLAN_FORMAT", "Ring", "Survey", "SurveyConfig", "SurveyError",
    "View", "ViewPlan", "ViewPlanConfig", "ClearanceCheck", "KnownCell", "hull_vertices",
    "object_contacts",
    "arm_collisions", "arm_link_bodies", "candidates",
    "check_paths", "clearance_violations", "fill_at_distance", "object_bodies",
    "object_bounding_sphere", "order_for_rail", "plan_capture", "plan_from_json", "plan_to_json",
    "plan_views", "ring_distance", "ring_phases", "ring_size", "ring_sizes", "ring_views",
    "robot_bodies", "rolled", "solve_views", "survey_object", "views_problem",
]
