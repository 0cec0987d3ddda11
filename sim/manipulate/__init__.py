"""Manipulation: the arm grasps a link of the object and moves it along an estimated joint.

``python -m sim.manipulate SCENE [--model MODEL.json] [--angle DEG | --distance M] --out DIR``

The robot decides from what it knows (:mod:`.planning`): its arm, the stage, and the registered
model of the object. From the model it takes the joint to move, the link to grasp (the joint's
child in the model's tree), grasp candidates on that link's reconstructed surface (also on sides
its camera cannot see now), whether each is hidden from the wrist camera at the arm's current
pose (rays against the model), the approach (from the model's normals), the clearance and the
arm's contacts (the model as spheres in a planning world), and the direction and size of the
motion (the model's joint motion A -> B). Ground truth enters only afterwards, in scoring.

The plan is then executed in MuJoCo physics (:mod:`.execute`) with a gripper whose grip has a
limit: it lets go when the force or torque needed to drag the object along the arm's path
exceeds it, so a wrong axis fails instead of dragging the object through its joint.

:func:`manipulate` ties the two together. Without a registered model it follows a joint given by
the caller on the true object's geometry: a demonstration (the command without ``--model``, the
tests that compare a true axis with a tilted one), never the harness's plan.
"""

from __future__ import annotations

import logging

import numpy as np

from sim.manipulate.estimate import (
    WRONG_AXIS_TILT_DEG,
    GraspMissed,
    JointEstimate,
    ManipulationError,
    default_joint,
    joint_estimate_from_model,
    joint_estimate_from_scene,
)
from sim.manipulate.execute import GripConfig, ManipulationResult, achieved_along
from sim.manipulate.execute import execute as execute_plan
from sim.manipulate.planning import (
    GraspCandidate,
    PlanningConfig,
    PlanningWorld,
    model_grasp_candidates,
    plan_candidate,
    plan_grasp,
    rank,
    replay_plan,
    scene_grasp_candidates,
)
from sim.manipulate.world import World, build_world, fresh_data
from sim.scene import body_subtree

log = logging.getLogger(__name__)


def moving_links(registered, joint: int) -> set[int]:
    """The model links that move with joint ``joint``'s child: the child and its descendants in
    the model's tree."""
    out, todo = set(), [registered.joints[joint].child]
    while todo:
        k = todo.pop()
        out.add(k)
        todo += registered.children_of(k)
    return out


def manipulate(scene, estimate: JointEstimate, amount: float, *, registered=None,
               model_joint: int | None = None, candidates=None, grasp_point=None,
               grasp_normal=None, grasp_roll_deg: float | None = None, q_start=None,
               prefer_hidden: bool = True,
               record_every: float | None = None, seed: int = 0, world: World | None = None,
               joint: str | None = None, planning: PlanningWorld | None = None,
               grip: GripConfig | None = None,
               planning_config: PlanningConfig | None = None) -> ManipulationResult:
    """Plan a grasp and a motion by ``amount`` along ``estimate``, and run it in physics.

    Parameters
    ----------
    scene : sim.scene.Scene
        The scene (the object in configuration A). With ``registered`` only its file and compiled
        model are used (the simulator), never its ground truth.
    estimate : JointEstimate
        The joint to follow, world frame (from the model: :func:`joint_estimate_from_model`).
    amount : float
        Requested displacement: rad (revolute) or m (prismatic), positive about/along the axis.
    registered : artrecon.model.ArticulatedModel, optional
        The registered model (robot frame, metres): the plan is made from it alone.
    model_joint : int, optional
        Index of the model's joint ``estimate`` comes from: its child link is grasped.
    candidates : list of GraspCandidate, optional
        Grasp points to choose from instead of the default ones.
    grasp_point, grasp_normal : (3,) float, optional
        Grasp exactly here (no ranking); the normal defaults to +z.
    grasp_roll_deg : float, optional
        With ``grasp_point``: the gripper's roll about the approach (deg) instead of the best of
        :attr:`PlanningConfig.rolls_deg` (the same grasp as an earlier plan's).
    q_start : (n,) float, optional
        The arm's current configuration (rail first); default its home keyframe. Visibility of
        grasp points is judged from the wrist camera at this pose.
    prefer_hidden : bool
        Prefer points the camera cannot see from ``q_start`` (the method's case).
    record_every : float, optional
        Keep a qpos snapshot every this many simulated seconds (for an image strip).
    seed : int
        Seed of the IK restarts.
    world : World, optional
        A :func:`build_world` result to reuse.
    joint : str, optional
        Without ``registered`` (demonstrations): the scene joint whose child link the default
        candidates lie on; default :func:`default_joint`.
    planning : PlanningWorld, optional
        A planning world to reuse.
    grip, planning_config : optional
        The gripper and the plan's settings.

    Returns
    -------
    ManipulationResult

    Raises
    ------
    ManipulationError
        No candidate can be grasped and moved, or the grasp could not be made.
    """
    grip = grip or GripConfig()
    planning_config = planning_config or PlanningConfig()
    if world is None:
        world = build_world(scene)
    data = fresh_data(world)
    q_start = world.kin.clip(np.asarray(data.qpos[world.qidx] if q_start is None else q_start,
                                        dtype=float))
    if planning is None:
        planning = (PlanningWorld.from_model(world, registered, planning_config)
                    if registered is not None else
                    PlanningWorld.from_scene(world, planning_config))
    if registered is not None:
        moving = moving_links(registered, model_joint) if model_joint is not None else set()
    else:  # the true world: the bodies that ride on the followed joint's child
        target = default_joint(scene) if joint is None else scene.joint(joint)
        root = scene.link(target.child).body_id
        moving = set(world.object_bodies) & set(body_subtree(world.model, root))
    if grasp_point is not None:
        n = np.array([0.0, 0.0, 1.0]) if grasp_normal is None else np.asarray(grasp_normal, float)
        (cand,) = planning.classify_visibility(
            q_start, [GraspCandidate(np.asarray(grasp_point, float), n / np.linalg.norm(n))])
        plan, why = plan_candidate(planning, cand, estimate, amount, q_start, seed, moving,
                                   None if grasp_roll_deg is None else (grasp_roll_deg,))
        if plan is None:
            raise ManipulationError(f"the given grasp point cannot be grasped and moved: {why}")
        summary = {"total": 1, "hidden": int(cand.hidden), "usable": 1,
                   "rejected_before_choice": [], "planned_in": planning.source}
        # the caller's point: its miss is the answer, no other point is tried
        return _execute(world, plan, estimate, amount, q_start, summary, planning.source, grip,
                        record_every)
    if candidates is None:
        if registered is not None:
            if model_joint is None:
                raise ValueError("give model_joint: the model's joint whose child to grasp")
            candidates = model_grasp_candidates(registered, model_joint, planning_config)
        else:
            candidates = scene_grasp_candidates(world, data, scene.link(target.child).body_ids)
    missed: list[dict] = []
    physics = None  # a missed grasp's simulation, which the next attempt goes on in
    while True:
        try:
            plan, summary = plan_grasp(planning, candidates, estimate, amount, q_start,
                                       prefer_hidden=prefer_hidden, seed=seed,
                                       moving_links=moving)
        except ManipulationError as err:
            if not missed:
                raise
            raise ManipulationError(f"{err} (after {_missed_text(missed)})") from err
        try:
            result = _execute(world, plan, estimate, amount, q_start, summary, planning.source,
                              grip, record_every, physics)
        except GraspMissed as miss:
            missed.append({"point": [float(x) for x in miss.point], "error": str(miss)})
            if len(missed) > planning_config.regrasps:
                if len(missed) == 1:
                    raise
                raise GraspMissed(f"{miss} (after {_missed_text(missed[:-1])})", miss.point,
                                  miss.physics) from miss
            # the arm has backed out the way it came, to q_start; the next attempt goes on in
            # the same physics (what this one touched stays touched), planned from the model
            # as before without the missed point's neighbours (the same widened rim)
            physics = miss.physics
            log.info("grasp at %s closed on nothing; planning again without the candidates "
                     "within %.0f mm of it", np.round(miss.point, 3).tolist(),
                     1e3 * planning_config.regrasp_exclusion)
            candidates = [c for c in candidates if float(np.linalg.norm(c.point - miss.point))
                          > planning_config.regrasp_exclusion]
            continue
        if missed:
            result.candidates["missed"] = missed
            result.log[:0] = [f"grasp {k + 1} of {len(missed) + 1} closed on nothing: "
                              f"{m['error']}" for k, m in enumerate(missed)]
        return result


def _execute(world, plan, estimate, amount, q_start, summary, planned_in, grip, record_every,
             physics=None):
    """:func:`execute_plan` (in ``physics`` when given), the hidden grasp point said in the
    log."""
    c = plan.candidate
    if c.hidden:
        log.info("grasp point %s is HIDDEN from the wrist camera at the current pose (%s)",
                 np.round(c.point, 3).tolist(), c.visibility)
    result = execute_plan(world, plan, estimate, amount, q_start, candidates_summary=summary,
                          planned_in=planned_in, grip=grip, record_every=record_every,
                          physics=physics)
    if c.hidden:
        result.log.insert(0, f"grasp point {np.round(c.point, 3).tolist()} is HIDDEN from the "
                             f"wrist camera at the current pose ({c.visibility})")
    return result


def _missed_text(missed: list[dict]) -> str:
    return (f"{len(missed)} grasp(s) that closed on nothing, at "
            + "; ".join(str(np.round(m["point"], 3).tolist()) for m in missed))


def replay(scene, estimate: JointEstimate, amount: float, run: dict, *, q_start=None,
           world: World | None = None, grip: GripConfig | None = None,
           planning_config: PlanningConfig | None = None) -> ManipulationResult:
    """An earlier run's grasp replayed in physics, then moved by ``amount`` along ``estimate``.

    The same grasp on the object (the run's ``grasp_point``, ``grasp_normal``,
    ``grasp_roll_deg``) reached by the same arm configurations (its ``approach``: pre-grasp to
    grasp) from the same start (its ``q_start``, unless given): only the motion is new
    (:func:`sim.manipulate.planning.replay_plan`). Nothing is planned again, so the true
    world's checks cannot pick another roll or refuse the grasp: scoring's force reference
    (:func:`sim.evaluate.scoring.manipulation_reference_stage`) moves the run's own grasp along
    the true joint, and the run's force is compared with like.

    Raises
    ------
    ManipulationError
        The run holds no approach (it failed before the grasp), the motion from its grasp leaves
        the arm's workspace, or the grasp is not made in physics.
    """
    grip = grip or GripConfig()
    planning_config = planning_config or PlanningConfig()
    if not run.get("approach"):
        raise ManipulationError("the run to replay holds no approach (it made no grasp)")
    if world is None:
        world = build_world(scene)
    q_start = np.asarray(run["q_start"] if q_start is None else q_start, float)
    cand = GraspCandidate(np.asarray(run["grasp_point"], float),
                          np.asarray(run["grasp_normal"], float),
                          bool(run.get("grasp_hidden")), run.get("grasp_visibility", ""))
    plan, why = replay_plan(world.kin, planning_config, cand, float(run["grasp_roll_deg"]),
                            np.asarray(run["approach"], float), estimate, amount,
                            travel=run.get("travel"))
    if plan is None:
        raise ManipulationError(f"the run's grasp cannot be replayed: {why}")
    return execute_plan(world, plan, estimate, amount, q_start,
                        candidates_summary={"replayed": True},
                        planned_in="replay of the run's grasp", grip=grip)


__all__ = [
    "GraspCandidate", "GraspMissed", "GripConfig", "JointEstimate", "ManipulationError",
    "ManipulationResult",
    "PlanningConfig", "PlanningWorld", "WRONG_AXIS_TILT_DEG", "World", "achieved_along",
    "build_world", "default_joint", "execute_plan", "fresh_data", "joint_estimate_from_model",
    "joint_estimate_from_scene", "manipulate", "model_grasp_candidates", "moving_links",
    "plan_candidate", "plan_grasp", "rank", "replay", "scene_grasp_candidates",
]
