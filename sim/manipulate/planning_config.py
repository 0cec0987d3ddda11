"""Settings of the robot's plan: one frozen dataclass, :class:`PlanningConfig`, read by the grasp
candidates (:mod:`.candidates`), the planning world's questions (:mod:`.planning_world`) and the
ranking and IK of the plan (:mod:`.planning`). Each field says why it has its value."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PlanningConfig:
    """Settings of the plan."""

    voxel: float = 0.006
    """model points are merged per voxel of this size (m) into one sphere"""
    sphere_radius: float = 0.004
    """radius of a model sphere (m): with 6 mm voxels neighbouring spheres overlap, so rays do
    not slip through a surface"""
    candidate_voxel: float = 0.006
    """grasp candidates: one per voxel of this size (m) of the child link's points (1 cm voxels
    on scissors' 3 mm blades mixed top and side normals: 20 candidates, 3 usable, none
    graspable; 6 mm: 103, 20 usable)"""
    min_normal_agreement: float = 0.8
    """a voxel's mean normal shorter than this (its normals disagree: an edge or noise) and the
    voxel is no candidate"""
    normal_radius: float = 0.01
    """a candidate's normal is the normal of the plane fitted to the link's points within this
    distance (m) that face like the voxel's mean normal: the mean of a few noisy point normals
    tilted the approach (scissors' rings, flat on the table, had voxel normals up to 14 deg off
    the vertical, and one fingertip dipped into the ring beside: no grasp among 39 candidates;
    with the fitted plane, the blade grasped at its tip)"""
    support_radius: float = 0.015
    """a candidate must lie on a surface of the model: at least ``min_support`` of the link's
    points within this distance (m) of it (a few stray points of a reconstruction -- points off
    the object -- are no place to grasp) ..."""
    min_support: int = 20
    """... (about a 1.5 cm disc of a surface sampled every 2-3 mm holds 60-100)"""
    edge_margin: float = 0.004
    """a candidate's own face must reach this far (m) beyond it in four directions of its
    tangent plane: a point on the rim of a face is not grasped (cabinet's drawer handle, 16 mm
    high, grasped at its lower rim: the fingertips' ray passed under the true handle)"""
    min_sphere_points: int = 2
    """a model sphere stands for a voxel with at least this many points (a single stray point
    blocks no approach)"""
    grasp_standoff: float = 0.018
    """the grasp frame (15 mm behind the fingertips) sits this far off the surface along the
    normal: the fingertips stop 3 mm short of it"""
    pregrasp_distance: float = 0.07
    """pre-grasp pose: this much further out along the normal"""
    occlusion_margin: float = 0.003
    """a point is hidden when the camera ray meets a surface this much (m) before the point's
    own sphere"""
    hidden_margin: float = 0.006
    """a point counts as hidden only when the camera rays to it and to four points this far (m)
    around it, lifted this far off the surface, are all blocked: a point at the edge of what
    the camera sees (a back face seen over a panel's rim) is hidden from the model's spheres
    and visible on the true object by a hair, and is called visible"""
    camera_ray_start: float = 0.001
    """the camera's rays start this far (m) in front of its centre: the Panda's wrist camera
    sits on the face of its housing (a box of the hand, another body than the one carrying the
    camera), and a ray from the centre met that face at distance 0 by rounding -- at the pose of
    pliers_panda's fresh view every candidate was "occluded by" the housing"""
    gripper_contact_radius: float = 0.03
    """at the grasp pose the gripper may touch the grasped link within this distance (m) of the
    grasp point (it is meant to) ..."""
    gripper_contact_depth: float = 0.004
    """... met no deeper than this (m): the fingertips stop 3 mm short of the surface and the
    model's spheres (``sphere_radius``) stand 4 mm out of it, so a grasp meets them about 1 mm
    deep; deeper than a sphere's radius the gripper is past the model's surface, inside the
    link (any depth was allowed, and a gripper plunging into the grasped link passed) ..."""
    face_contact_radius: float = 0.05
    """... and on the grasped face (spheres of the grasped link within this distance (m) of the
    grasp point ...)"""
    face_contact_depth: float = 0.002
    """... and met no deeper than this (m): the fingertips graze the spheres, 4 mm high, of
    the face they stop 3 mm short of): the finger pads reach 4 cm from the grasp point, and on
    a flat face every grasp met the face's own spheres beyond 3 cm (the truck's bed side
    planned on its true surfaces: 40 candidates refused for it); any other contact of the arm
    is a collision (a finger against the side of a handle goes deeper)"""
    face_height: float = 0.005
    """... both only for spheres on the grasped face: their centres (the mean of a voxel's
    points, on the surface) at most this far (m) out of it along the grasp normal. A part of
    the grasped link standing proud of the face near the grasp point is an obstacle: the
    fingers stop on it (cabinet seed 2: the grasp point 3 mm above the drawer's handle, which
    stands 1.3-2.5 cm out of the front; both contact allowances let the fingers come down onto
    the handle's spheres, and in physics they stopped 5 mm short of the grasp pose)"""
    approach_radius: float = 0.025
    """free space in front of a candidate: rays along the normal from the point and from four
    points this far (m) around it (the fingertips sit 3 cm off the approach axis) ..."""
    approach_free_length: float = 0.3
    """... must meet nothing for this long (m): gripper and wrist"""
    min_lever: float = 0.06
    """revolute joints: candidates nearer the estimated axis than this (m) are not used (a
    short lever turns the gripper a lot for little motion and needs large forces) ..."""
    min_lever_fraction: float = 0.6
    """... unless the link reaches no farther than ``min_lever`` from its axis (a Barrett
    finger turning about its spread axis reaches 4.7 cm): then points beyond this fraction of
    its reach"""
    min_normal_z: float = -0.3
    """candidates whose normal points down more steeply than this are not approached (from
    below, through the table)"""
    rolls_deg: tuple[float, ...] = (0, 45, 90, 135, 180, 225, 270, 315)
    """rolls of the gripper about the approach axis tried per candidate (deg)"""
    max_candidates: int = 80
    """candidates planned, in order of preference, before giving up (40 before 2fdffd3: on the
    view plan of a half-size survey, ``sim.views.SurveyConfig.image_scale`` 0.5, the imported
    chest's lid was grasped at its 55th candidate, its front face, after 54 along the top of
    its front edge out of reach). A scene planned within 40 plans the same grasp either way;
    only a search that would have given up goes on"""
    pull_alignment_deg: float = 30.0
    """candidates whose normal lies within this angle (deg) of the motion's direction at their
    point rank first (:func:`sim.manipulate.planning.rank`)"""
    facing_min_turn: float = 0.35
    """the last start of a candidate's IK, home with the rail turned to the grasp's side
    (:func:`sim.manipulate.planning.facing_start`), is tried only when the rail turns by at
    least this much (rad) from the start and from home: nearer, it is the same branch"""
    facing_min_horizontal: float = 0.3
    """a normal with less horizontal component than this faces up or down: the grasp's side is
    then the point's own azimuth about the rail's axis"""
    regrasps: int = 2
    """grasps tried again after one that closed on nothing (:class:`GraspMissed`: the model's
    surface was not where the object is there): the arm backs out the way it came and the plan
    starts over without the candidates near the missed one, in the same physics (what the miss
    touched on its way stays touched). scraper_truck at seed 1 (2026-11-29, an AMD EPYC)
    grasped its boom 1 mm below the boom's side face, on a dense surface widened 5 mm beyond
    the face's lower rim, which the candidate's rim check (``edge_margin``) took for face; a
    6 mm margin avoids that miss but leaves scissors' thin blades without a movable grasp
    (seeds 1 and 2). 0: one grasp, its miss the manipulation's end"""
    regrasp_exclusion: float = 0.015
    """after a miss, candidates within this distance (m) of the missed point are not tried: the
    same widened rim"""
    retry_spacing: float = 0.015
    """after a candidate failed, the next one tried lies at least this far (m) from every one
    tried (the nearer ones come after the others): what stops one candidate (out of reach,
    the table, a fixed part in the fingers' way) stops its neighbours too, and the 40 tries
    had gone to the voxels along one edge of chest's lid"""
    clear_of_fixed: float = 0.035
    """candidates at least this far (m) from every model surface that does not move with the
    grasped link come first (the fingertips sit 3 cm either side of the grasp point: a grasp
    this far from the fixed parts neither touches them nor passes them by a hair as it moves;
    cabinet_door_only's door grasped at its edge met the carcass's side early in the turn) ..."""
    min_clear_of_fixed: float = 0.008
    """... then those at least this far; nearer ones last (the model's surfaces lie a few mm
    from the true ones: a finger planned to pass a fixed part this close may touch it)"""
    waypoint_angle: float = np.deg2rad(1.0)
    """motion waypoints: one per this much rotation (rad) ..."""
    waypoint_distance: float = 0.002
    """... or translation (m) ..."""
    min_waypoints: int = 20
    """... and at least this many"""
    max_waypoint_joint_step: float = 0.15
    """largest joint change between waypoints (rad): larger means the IK jumped branches"""
    motion_checks: int = 12
    """configurations checked for contacts along the motion (every ``len // motion_checks``-th
    waypoint)"""
    travel_joint_step: float = 0.005
    """the travel from the arm's current pose to the pre-grasp pose (a straight line in joint
    space, as execution follows it) is checked for contacts at configurations no more than this
    far apart (rad) in any joint: 5 mm at a 1 m lever, within ``travel_clearance`` (12 checks
    over the whole travel, up to 0.2 rad apart, saw nothing between them) ..."""
    travel_clearance: float = 0.005
    """... and the arm passes the model's spheres no closer than this (m): the model's surfaces
    lie a few mm from the true ones (cabinet_door_only's travel passed the model's carcass by
    0.6 mm and touched the true cabinet_top, 0.1 mm deep); the stage, which the robot knows,
    keeps no margin"""
    max_path_kink: float = 0.3
    """the motion's joint path may change its step between waypoints by at most this share of
    its largest step: a joint that meets its limit mid-motion stops dead while the others take
    over in one step, and the arm's inertia turns that corner into a jolt of the grasp's force
    (cabinet's drawer planned on the true surfaces: the wrist's joint5 met its limit at 70% of
    the pull, 9.7 N for a joint that needs 0.7 N, the grasp lost in another plan; its door
    planned on the model: joint5 stopped within two waypoints, 21.9 N)"""
    joint_limit_margin: float = np.deg2rad(2.0)
    """the grasp, approach and motion keep every arm joint this far (rad) inside its limits:
    the IK puts a joint exactly on its limit when the target asks for more, and the servo, a
    hair behind or ahead of its command, would meet the limit's hard stop through the stiff
    grasp"""



__all__ = ["PlanningConfig"]
