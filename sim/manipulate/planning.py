"""The robot's plan, made from what the robot knows: its own arm, the stage it works on, and the
registered model of the object.

The plan is made in three rooms:

- :mod:`.candidates`: grasp candidates, points of the model's child link with their normals
  (:func:`model_grasp_candidates`), and the grasp frame at one (:func:`grasp_frame`);
- :mod:`.planning_world`: :class:`PlanningWorld`, the scene's stage and arm with the object
  replaced by the registered model (one small sphere per voxel of the model's points), where
  every question is asked: whether a candidate is hidden from the wrist camera at the arm's
  current pose, free space in front of it, its clearance from the fixed parts, the arm's
  contacts at a configuration, along the travel to the pre-grasp pose and along the motion
  (the links the joint moves carried with it);
- this module: the ranking (hidden first, clear of the fixed parts, the longest lever about the
  estimated axis; :func:`rank`), the IK of the grasp, the approach and the motion along the
  estimated joint (:func:`plan_candidate`), and the first candidate that works
  (:func:`plan_grasp`).

Their settings are one :class:`PlanningConfig` (:mod:`.planning_config`).
``PlanningWorld.from_scene`` keeps the true object instead (demonstrations that follow the
ground-truth joint, and the tests that compare the two); the harness never uses it.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from sim.manipulate.candidates import (
    GraspCandidate,
    grasp_frame,
    model_grasp_candidates,
    scene_grasp_candidates,
    voxel_centres,
)
from sim.manipulate.estimate import JointEstimate, ManipulationError
from sim.manipulate.planning_config import PlanningConfig
from sim.manipulate.planning_world import PlanningWorld


@dataclass
class Plan:
    """The grasp and motion the arm will execute."""

    candidate: GraspCandidate
    roll_deg: float
    T_grasp: np.ndarray
    q_pre: np.ndarray
    q_grasp: np.ndarray
    approach: np.ndarray
    """(k, n) joint waypoints pre-grasp -> grasp"""
    s: np.ndarray
    """(N+1,) path parameter of the motion waypoints"""
    q_path: np.ndarray
    """(N+1, n) joint waypoints of the motion"""
    p_path: np.ndarray
    """(N+1, 3) planned grasp-frame positions"""
    tried: list = field(default_factory=list)
    """why the candidates ranked before this one were passed over"""
    gripper_contacts: int = 0
    """contacts of the gripper with the model at the grasp pose (:meth:`PlanningWorld.
    gripper_contacts`): the fingers resting on the object, not straddling it"""
    travel: np.ndarray | None = None
    """(k, n) arm waypoints from the start to the pre-grasp pose when the straight line between
    them is blocked (:func:`retreat_travel`); None: the straight line"""



def rank(candidates: list[GraspCandidate], est: JointEstimate, prefer_hidden: bool,
         config: PlanningConfig | None = None) -> list[GraspCandidate]:
    """Usable candidates, best first: those nearer than
    :attr:`PlanningConfig.min_clear_of_fixed` to a fixed part of the model last, hidden or not;
    among the others hidden ones first when ``prefer_hidden`` (the method's case: a point the
    camera cannot see now), then by their clearance from the fixed parts
    (:attr:`PlanningConfig.clear_of_fixed`), then those whose normal lies along the motion
    there (a pull or push along the gripper's axis: a door's handle from the front, not at its
    corner, where cabinet's grasp with the normal 53 deg off the motion needed 8.3 N along the
    true joint and let go at 1% of the turn over the 3 N m limit), then the longest lever about
    the estimated axis (revolute) or the highest point (prismatic). Candidates facing the table
    and, for a revolute joint, too near its axis are left out.

    A candidate a few millimetres from another link lies where the segmentation is least sure
    (the seam between two links): the imported chest's lid was grasped, as its only kind of
    hidden candidate, on its front edge 4.9 mm above the carcass's points, and the gripper
    closed on the carcass's front panel (the lid did not move). Being hidden is what the method
    shows, not a reason to grasp at a seam."""
    config = config or PlanningConfig()
    def lever(c):
        v = c.point - est.point
        return float(np.linalg.norm(v - np.dot(v, est.axis) * est.axis))

    reach = max((lever(c) for c in candidates), default=0.0)
    min_lever = min(config.min_lever, config.min_lever_fraction * reach)
    usable = [c for c in candidates if c.normal[2] >= config.min_normal_z
              and (est.type != "revolute" or lever(c) >= min_lever)]

    def pulls(c) -> bool:
        """The candidate's normal lies along the motion at its point (within
        :attr:`PlanningConfig.pull_alignment_deg`): the arm pulls or pushes along the gripper's
        own axis, the part held between the fingers."""
        t = np.asarray(est.axis, float)
        if est.type == "revolute":
            t = np.cross(t, c.point - est.point)
        norm = float(np.linalg.norm(t))
        return norm > 0 and abs(float(np.dot(c.normal, t))) / norm >= np.cos(
            np.deg2rad(config.pull_alignment_deg))

    def key(c):
        hidden_rank = 0 if (c.hidden == prefer_hidden) else 1
        tier = (0 if c.clearance >= config.clear_of_fixed else
                1 if c.clearance >= config.min_clear_of_fixed else 2)
        return (tier == 2, hidden_rank, tier, not pulls(c),
                -lever(c) if est.type == "revolute" else -c.point[2])

    return sorted(usable, key=key)


def plan_candidate(pw: PlanningWorld, cand: GraspCandidate, est: JointEstimate, amount: float,
                   q_start: np.ndarray, seed: int, moving_links=(), rolls_deg=None
                   ) -> tuple[Plan | None, str]:
    """IK of the grasp, pre-grasp and approach, and of every waypoint of the motion by
    ``amount`` along ``est``, for each roll (``rolls_deg``, default
    :attr:`PlanningConfig.rolls_deg`); contacts checked in the plan's world (along the motion,
    the model links ``moving_links`` carried by ``est``: :func:`motion_contacts`); every arm joint
    kept :attr:`PlanningConfig.joint_limit_margin` inside its limits. Of the rolls that pass, those
    whose gripper touches nothing of the model at the grasp pose come first (the part under the
    grasp point between the fingers, not under them: a finger resting on the object 3 mm above
    the model's surface presses into it where the true surface lies further out -- the model
    rounds a sharp edge, and cabinet_door_only's door handle grasped at its corner with the
    fingers along it, 5 mm out of the model there, lost the grasp at 1% of the turn, 8.4 N and
    3.0 N m, where a roll with the fingers either side of the handle turned it at 3 N); then the
    shortest travel. The IK starts from ``q_start``; when no roll passes from there, it starts
    again from the arm's home configuration (:attr:`PlanningWorld.q_home`: another branch of
    the arm's IK, whose travel from ``q_start`` is checked like any other), and then from home
    with the rail turned to the side the grasp faces (:func:`facing_start`). The plan, or None
    and why."""
    rolls = pw.config.rolls_deg if rolls_deg is None else tuple(rolls_deg)
    q_start = np.asarray(q_start, float)
    with _limits_narrowed(pw.kin, pw.config.joint_limit_margin):
        plan, why = _plan_candidate(pw, cand, est, amount, q_start, q_start, seed,
                                    moving_links, rolls)
        if plan is not None or np.allclose(pw.q_home, q_start):
            return plan, why
        home, why_home = _plan_candidate(pw, cand, est, amount, q_start, pw.q_home, seed,
                                         moving_links, rolls)
        if home is not None:
            return home, ""
        why = f"{why} | from home: {why_home}"
        facing = facing_start(pw, cand, (q_start, pw.q_home))
        if facing is None:
            return None, why
        plan, why_facing = _plan_candidate(pw, cand, est, amount, q_start, facing, seed,
                                           moving_links, rolls)
    return (plan, "") if plan is not None else (None, f"{why} | facing: {why_facing}")


def facing_start(pw: PlanningWorld, cand: GraspCandidate, tried=()) -> np.ndarray | None:
    """The arm's home posture on the rail turned to the side the grasp faces: the shoulder at the
    azimuth of the candidate's outward normal (of the point itself, about the rail's axis, when
    the normal is near vertical). From the start pose and from home, the IK keeps the rail where
    it is and reaches a face turned away from the arm around or through the object (the door of
    cabinet_door_only grasped at its outer edge, from a start on the other side of the table:
    every candidate touched the model). None when the rail would turn by less than
    :attr:`PlanningConfig.facing_min_turn` from every start in ``tried``."""
    n = np.asarray(cand.normal, float)
    horizontal = n[:2] if np.hypot(*n[:2]) >= pw.config.facing_min_horizontal else cand.point[:2]
    q = np.array(pw.q_home, float)
    q[0] = pw.kin.rail_angle_for_azimuth(float(np.arctan2(horizontal[1], horizontal[0])))
    for t in tried:
        turn = abs((q[0] - float(np.asarray(t)[0]) + np.pi) % (2 * np.pi) - np.pi)
        if turn < pw.config.facing_min_turn:
            return None
    return q


def motion_waypoints(est: JointEstimate, amount: float, cfg: PlanningConfig) -> np.ndarray:
    """The path parameter of the motion's waypoints: one per :attr:`PlanningConfig.
    waypoint_angle` (revolute) or ``waypoint_distance`` (prismatic) of ``amount``, at least
    ``min_waypoints``."""
    n_way = max(cfg.min_waypoints, int(np.ceil(abs(amount) / (
        cfg.waypoint_angle if est.type == "revolute" else cfg.waypoint_distance))))
    return np.linspace(0.0, 1.0, n_way + 1)


def motion_path(kin, cfg: PlanningConfig, est: JointEstimate, amount: float, T_g: np.ndarray,
                q_grasp: np.ndarray, s: np.ndarray):
    """The arm's waypoints of the motion by ``amount`` along ``est`` from the grasp pose ``T_g``
    held at ``q_grasp``: the IK of the grasp frame carried by the joint's motion at each ``s``,
    each from the one before, no joint stepping more than
    :attr:`PlanningConfig.max_waypoint_joint_step`.

    Returns
    -------
    q_path : (k, n) float
    p_path : (k, 3) float
        the grasp frame's planned positions
    stop : float or None
        where along the path the IK failed (None: the whole path, ``k == len(s)``)
    """
    q = np.asarray(q_grasp, float)
    q_path, p_path = [q], [T_g[:3, 3].copy()]
    for sk in s[1:]:
        T = est.motion(sk * amount) @ T_g
        r = kin.solve_ik(T, "grasp", q, restarts=0)
        if not r.success or np.max(np.abs(r.q - q)) > cfg.max_waypoint_joint_step:
            return np.array(q_path), np.array(p_path), float(sk)
        q_path.append(r.q)
        p_path.append(T[:3, 3].copy())
        q = r.q
    return np.array(q_path), np.array(p_path), None


def motion_contacts(pw: PlanningWorld, est: JointEstimate, amount: float,
                    cand: GraspCandidate, q_path: np.ndarray, s: np.ndarray, moving_links
                    ) -> list[str]:
    """Contacts of the arm along the motion (every ``len // motion_checks``-th waypoint of
    ``q_path``, at the path parameters ``s``), the model links ``moving_links`` carried there by
    the estimated joint (:meth:`PlanningWorld.arm_contacts` with ``carry``): the gripper may
    touch the grasped link where it holds it, nothing else (the arm's forearm sweeping into
    the door it turns is a collision). The contacts at the first waypoint that has any."""
    step = max(1, len(q_path) // pw.config.motion_checks)
    for qk, sk in zip(q_path[step::step], s[step:len(q_path):step], strict=True):
        T = est.motion(sk * amount)
        hits = pw.arm_contacts(qk, grasp_point=T[:3, :3] @ cand.point + T[:3, 3],
                               grasp_links=moving_links, grasp_normal=T[:3, :3] @ cand.normal,
                               moving_links=moving_links, carry=T)
        if hits:
            return hits
    return []


def replay_plan(kin, cfg: PlanningConfig, cand: GraspCandidate, roll_deg: float,
                approach: np.ndarray, est: JointEstimate, amount: float, travel=None
                ) -> tuple[Plan | None, str]:
    """An earlier plan's grasp, replayed: the same grasp frame on the object (``cand``'s point
    and normal, the gripper's ``roll_deg``), the same arm configurations (``approach``: the
    earlier plan's waypoints from its pre-grasp pose to its grasp pose), and a new motion by
    ``amount`` along ``est`` from there (:func:`motion_path`), reached by the earlier plan's
    ``travel`` if it had one. Nothing is planned again and
    nothing checked for contacts: scoring's force reference, which measures what the true joint
    asks of this grasp. The plan, or None and why."""
    approach = np.atleast_2d(np.asarray(approach, float))
    T_g = grasp_frame(cand.point, cand.normal, roll_deg, cfg.grasp_standoff)
    s = motion_waypoints(est, amount, cfg)
    with _limits_narrowed(kin, cfg.joint_limit_margin):
        q_path, p_path, stop = motion_path(kin, cfg, est, amount, T_g, approach[-1], s)
    if stop is not None:
        return None, (f"the motion from the replayed grasp leaves the workspace or joint limits "
                      f"at {stop * 100:.0f}% of the path")
    return Plan(cand, float(roll_deg), T_g, approach[0], approach[-1], approach, s, q_path,
                p_path, travel=None if not travel else np.asarray(travel, float)), ""


def retreat_travel(pw: PlanningWorld, q_start, q_pre) -> np.ndarray:
    """The travel from ``q_start`` to ``q_pre`` by the arm's home posture: up into it where the
    rail stands, the rail turned to the pre-grasp's, down to the pre-grasp pose ((4, n) joint
    waypoints). For a grasp on the far side of the object from where the arm is (the fresh
    view's pose), where the straight joint-space line sweeps the arm through the object."""
    q_start, q_pre = np.asarray(q_start, float), np.asarray(q_pre, float)
    up = np.array(pw.q_home, float)
    up[0] = q_start[0]
    over = np.array(pw.q_home, float)
    over[0] = q_pre[0]
    return np.array([q_start, up, over, q_pre])


def _kink(q_path: np.ndarray, window: int = 3) -> tuple[float, int] | None:
    """The largest change of the joint steps between motion waypoints ``window`` apart, as a
    share of the largest step, and the waypoint where it happens (None: too few waypoints).
    Waypoints uniform along a smooth motion give a smooth joint path (shares of a few
    hundredths); a joint that runs into its limit stops within a waypoint or two while the
    others take over its part of the motion."""
    steps = np.diff(q_path, axis=0)
    w = min(window, len(steps) - 1)
    if w < 1:
        return None
    scale = float(np.abs(steps).max())
    if scale <= 0:
        return None
    change = np.abs(steps[w:] - steps[:-w]).max(axis=1)
    k = int(np.argmax(change))
    return float(change[k]) / scale, k + (w + 1) // 2


@contextmanager
def _limits_narrowed(kin, margin: float):
    """The IK of ``kin`` (the planning world's own) kept ``margin`` inside every joint limit
    (joints whose range is not at least four margins wide keep theirs)."""
    lower, upper = kin.lower, kin.upper
    span = upper - lower
    m = np.where(np.isfinite(span) & (span > 4 * margin), margin, 0.0)
    kin.lower, kin.upper = lower + m, upper - m
    try:
        yield
    finally:
        kin.lower, kin.upper = lower, upper


def _plan_candidate(pw: PlanningWorld, cand: GraspCandidate, est: JointEstimate, amount: float,
                    q_start: np.ndarray, q_seed: np.ndarray, seed: int, moving_links, rolls
                    ) -> tuple[Plan | None, str]:
    kin, cfg = pw.kin, pw.config
    s = motion_waypoints(est, amount, cfg)
    reasons = []
    best = None
    # cheap first test: can the grasp frame's origin get there at all (any orientation)?
    reach = kin.solve_ik(grasp_frame(cand.point, cand.normal, 0.0, cfg.grasp_standoff), "grasp",
                         q_seed, position_only=True, restarts=2, seed=seed)
    if not reach.success:
        return None, (f"out of reach: the grasp frame gets no closer than "
                      f"{1e3 * reach.position_error:.0f} mm")
    for roll in rolls:
        T_g = grasp_frame(cand.point, cand.normal, roll, cfg.grasp_standoff)
        ik = kin.solve_ik(T_g, "grasp", reach.q, restarts=2, seed=seed)
        if not ik.success:
            reasons.append(f"roll {roll}: grasp pose unreachable")
            continue
        T_pre = T_g.copy()
        T_pre[:3, 3] += cfg.pregrasp_distance * cand.normal
        pre = kin.solve_ik(T_pre, "grasp", ik.q, restarts=0)
        if not pre.success:
            reasons.append(f"roll {roll}: pre-grasp unreachable")
            continue
        hits = (pw.arm_contacts(ik.q, grasp_point=cand.point, grasp_links=moving_links,
                                grasp_normal=cand.normal)
                or pw.arm_contacts(pre.q))
        if hits:
            reasons.append(f"roll {roll}: arm touches {hits[0]}")
            continue
        approach, q, ok = [pre.q], pre.q, True
        for f in np.linspace(0, 1, 9)[1:]:
            T = T_g.copy()
            T[:3, 3] += (1 - f) * cfg.pregrasp_distance * cand.normal
            r = kin.solve_ik(T, "grasp", q, restarts=0)
            if not r.success or np.max(np.abs(r.q - q)) > cfg.max_waypoint_joint_step:
                ok = False
                break
            approach.append(r.q)
            q = r.q
        if not ok:
            reasons.append(f"roll {roll}: approach line not followable")
            continue
        hits, at = pw.approach_contacts(approach, cand.point, moving_links, cand.normal)
        if hits:
            reasons.append(f"roll {roll}: approach to the grasp meets {hits[0]} at "
                           f"{100 * at:.0f}% of the way")
            continue
        q_path, p_path, stop = motion_path(kin, cfg, est, amount, T_g, q, s)
        if stop is not None:
            reasons.append(f"roll {roll}: motion leaves the workspace or joint limits at "
                           f"{stop * 100:.0f}% of the path")
            continue
        kink = _kink(q_path)
        if kink is not None and kink[0] > cfg.max_path_kink:
            reasons.append(f"roll {roll}: the motion's joint path kinks at "
                           f"{100 * s[kink[1]]:.0f}% of the path (a joint held at its limit)")
            continue
        hits = motion_contacts(pw, est, amount, cand, q_path, s, moving_links)
        if hits:
            reasons.append(f"roll {roll}: the arm touches {hits[0]} during the motion")
            continue
        travel = None
        hits, at = pw.travel_contacts(q_start, pre.q)
        if hits:
            # the straight line sweeps the arm through the object: retreat, turn, come down
            via = retreat_travel(pw, q_start, pre.q)
            hits_via, at_via = pw.path_contacts(via)
            if hits_via:
                reasons.append(f"roll {roll}: travel to pre-grasp meets {hits[0]} at "
                               f"{100 * at:.0f}% of the way, by the home posture "
                               f"{hits_via[0]} at {100 * at_via:.0f}% (the model kept "
                               f"{1e3 * cfg.travel_clearance:.0f} mm off)")
                continue
            travel = via
        touch = pw.gripper_contacts(ik.q)
        length = float(np.sum(np.abs(pre.q - q_start))) if travel is None else float(
            np.sum(np.abs(np.diff(travel, axis=0))))
        cost = (touch > 0, length)
        plan = Plan(cand, float(roll), T_g, pre.q, ik.q, np.array(approach), s, q_path, p_path,
                    gripper_contacts=touch, travel=travel)
        if best is None or cost < best[0]:
            best = (cost, plan)
    if best is None:
        return None, "; ".join(reasons[:3])
    return best[1], ""


def _spread(ranked: list[GraspCandidate], spacing: float, budget: int):
    """``ranked`` in order, at most ``budget`` of them, each one after a failure at least
    ``spacing`` from every candidate tried before it (a generator: what it yields next depends
    on nothing but the order -- every candidate yielded before failed); the candidates it
    skipped follow, in order, when the others run out."""
    tried: list[np.ndarray] = []
    skipped = []
    for c in ranked:
        if len(tried) >= budget:
            return
        if tried and np.min(np.linalg.norm(np.array(tried) - c.point, axis=1)) < spacing:
            skipped.append(c)
            continue
        tried.append(c.point)
        yield c
    for c in skipped:
        if len(tried) >= budget:
            return
        tried.append(c.point)
        yield c


def plan_grasp(pw: PlanningWorld, candidates: list[GraspCandidate], est: JointEstimate,
               amount: float, q_start, *, prefer_hidden: bool = True, seed: int = 0,
               moving_links=()) -> tuple[Plan, dict]:
    """Classify, filter and rank ``candidates`` in the plan's world and plan the first that
    works. Returns the plan and a summary of the candidates.

    Raises
    ------
    ManipulationError
        No candidate can be grasped and moved (with the first reasons).
    """
    q_start = np.asarray(q_start, float)
    cands = pw.classify_visibility(q_start, candidates)
    n_hidden = sum(c.hidden for c in cands)
    ranked = rank(pw.fixed_clearance(pw.clear(cands), moving_links), est, prefer_hidden,
                  pw.config)
    tried = []
    for cand in _spread(ranked, pw.config.retry_spacing, pw.config.max_candidates):
        # one seed for every candidate: the same grasp point planned again (the force reference
        # along the true joint, in scoring) gets the same IK
        plan, why = plan_candidate(pw, cand, est, amount, q_start, seed, moving_links)
        if plan is not None:
            plan.tried = tried
            return plan, {"total": len(cands), "hidden": n_hidden, "usable": len(ranked),
                          "rejected_before_choice": tried[:10], "planned_in": pw.source}
        tried.append(f"{np.round(cand.point, 3).tolist()}: {why}")
    raise ManipulationError(
        f"no grasp candidate could be grasped and moved by {amount:g} along the {est.type} axis "
        f"({len(cands)} candidates, {n_hidden} hidden, {len(ranked)} usable, "
        f"{min(len(ranked), pw.config.max_candidates)} tried, planned in the "
        f"{pw.source}). First reasons: " + " | ".join(tried[:4]))



__all__ = ["PlanningConfig", "GraspCandidate", "Plan", "PlanningWorld", "grasp_frame",
           "model_grasp_candidates", "scene_grasp_candidates", "rank", "plan_candidate",
           "plan_grasp", "voxel_centres"]
