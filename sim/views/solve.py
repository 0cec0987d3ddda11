"""Reaching planned views: inverse kinematics (upright, then rolled), the clearance at each view,
and the straight joint-space moves between them."""

from __future__ import annotations

import logging

import mujoco
import numpy as np

from sim import robot
from sim.views.clearance import ClearanceCheck, arm_link_bodies, robot_bodies
from sim.views.records import View, ViewPlanConfig

log = logging.getLogger(__name__)

def rolled(T_world_camera: np.ndarray, roll_deg: float) -> np.ndarray:
    """The same camera turned by ``roll_deg`` about its optical axis (OpenCV z)."""
    a = np.deg2rad(roll_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    T = np.array(T_world_camera, dtype=float)
    T[:3, :3] = T[:3, :3] @ Rz
    return T


def _solve_one(model, data, kin, view: View, q_prev, *, seed: int, restarts: int,
               rolled_restarts: int, rolls, check: ClearanceCheck, qidx: np.ndarray,
               saved: np.ndarray) -> list[str]:
    """Try to reach ``view`` (upright first, then rolled), starting from ``q_prev`` and from the
    arm's default seed. Fills ``view.q`` (and its roll and pose) on success; returns the reasons
    of the failed attempts."""
    reasons = []
    for roll in rolls:
        T = rolled(view.T_world_camera, roll)
        # start from the previous view (short moves), else from the arm's default seed; the
        # upright view gets the full IK effort, the rolled fallbacks a few restarts each
        starts = [q_prev, None] if q_prev is not None else [None]
        for q0 in starts if roll == 0.0 else starts[:1]:
            res = robot.solve_view_ik(kin, T, q0, seed=seed,
                                      restarts=restarts if roll == 0.0
                                      else min(rolled_restarts, restarts))
            if not res.success:
                reasons.append(f"roll {roll:+.0f}: " + (
                    res.reason or f"IK {res.position_error * 1e3:.1f} mm "
                                  f"{np.rad2deg(res.rotation_error):.2f} deg off"))
                continue
            q = res.q if q_prev is None else kin.nearest_equivalent(res.q, q_prev)
            data.qpos[:] = saved
            data.qpos[qidx] = q
            hits = check(data)
            if hits:
                reasons.append(f"roll {roll:+.0f}: too close (clearance "
                               f"{check.clearance * 1e3:.0f} mm, contact within the arm): "
                               f"{', '.join(hits[:3])}")
                continue
            view.q, view.roll_deg, view.reason = q.copy(), roll, ""
            view.T_world_camera = T
            return []
    return reasons


def solve_views(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                views: list[View], *, seed: int = 0, progress=None, q_start=None,
                restarts: int | None = None, rolls=None, stop_at_first_failure: bool = False,
                config: ViewPlanConfig = ViewPlanConfig()) -> None:
    """Fill in ``q`` (or ``reason``) of every view: IK with joint limits, then a collision check.

    Views are solved in their order, each IK started at the previous view's solution (the rail
    makes neighbouring views of a ring need nearly the same arm configuration); a view that fails
    is tried once more from the solution of its nearest reachable neighbour on the other side.

    Parameters
    ----------
    model, data
        The scene; ``data`` holds its state (object configuration). Its arm joints are changed
        while solving and restored at the end.
    kin : robot.ArmKinematics
    views : list of View
        Solved in place.
    seed : int
        IK restarts of view ``v`` are seeded with ``seed + v.index``.
    progress : tqdm-like, optional
        ``update(1)`` per view.
    q_start : (n,) float, optional
        Solution of the view before the first (e.g. the previous ring's last view).
    restarts : int, optional
        Random IK restarts of the upright view (default ``config.ik_restarts``).
    rolls : sequence of float, optional
        Image rolls (degrees) tried in order (default ``config.roll_candidates_deg``).
    stop_at_first_failure : bool
        Leave the remaining views unsolved (``q`` None, reason ``"not tried"``) after the first
        unreachable one (to probe candidate rings quickly).
    config : ViewPlanConfig
        Its tunables of reaching a view: IK restarts (upright and rolled), the rolls and the
        clearance; its ring layout is not read.
    """
    qidx = robot.qpos_indices(model, kin)
    links = arm_link_bodies(model, kin)
    saved = data.qpos.copy()
    kw = dict(restarts=config.ik_restarts if restarts is None else restarts,
              rolled_restarts=config.rolled_ik_restarts,
              rolls=tuple(config.roll_candidates_deg if rolls is None else rolls),
              check=ClearanceCheck(model, links, robot_bodies(model, kin), config.clearance_m,
                                 config.self_clearance_m),
              qidx=qidx, saved=saved)
    q_prev = None if q_start is None else np.asarray(q_start, dtype=float)
    failed = False
    for view in views:
        view.q, view.reason = None, ""
        if failed and stop_at_first_failure:
            view.reason = "not tried"
            continue
        reasons = _solve_one(model, data, kin, view, q_prev, seed=seed + view.index, **kw)
        if view.reachable:
            q_prev = view.q
        else:
            view.reason = "; ".join(reasons)
            failed = True
        if progress is not None:
            progress.update(1)
    if not stop_at_first_failure:
        # second chance: start from the next reachable view (the pass came from the other side)
        for i, view in enumerate(views):
            if view.reachable:
                continue
            after = [v for v in views[i + 1:] if v.reachable]
            if after:
                _solve_one(model, data, kin, view, after[0].q, seed=seed + view.index, **kw)
    for view in views:
        if not view.reachable and view.reason != "not tried":
            log.info("view %d (ring %d, azimuth %.0f deg) unreachable: %s", view.index,
                     view.ring, np.rad2deg(view.azimuth), view.reason)
    data.qpos[:] = saved
    mujoco.mj_forward(model, data)


def check_paths(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                views: list[View], q_start=None,
                config: ViewPlanConfig = ViewPlanConfig()) -> None:
    """Check the straight joint-space move into every reachable view: the arm keeps
    ``config.clearance_m`` from everything outside the robot and ``config.self_clearance_m``
    from itself, at
    configurations at most ``config.path_check_step`` apart along the move.

    The arm travels from ``q_start`` (if given) to the first reachable view, then from each
    reachable view to the next, as :mod:`sim.capture` drives it. A view whose incoming move
    comes too close to something (the table, the object, the floor) or makes the arm touch
    itself is made unreachable with the reason, and the next move starts from the last view
    kept.
    """
    qidx = robot.qpos_indices(model, kin)
    links = arm_link_bodies(model, kin)
    check = ClearanceCheck(model, links, robot_bodies(model, kin), config.clearance_m,
                           config.self_clearance_m)
    saved = data.qpos.copy()
    q_prev = None if q_start is None else np.asarray(q_start, dtype=float)
    for view in views:
        if not view.reachable:
            continue
        if q_prev is not None:
            n = max(1, int(np.ceil(np.max(np.abs(view.q - q_prev)) / config.path_check_step)))
            for t in np.arange(1, n) / n:
                data.qpos[:] = saved
                data.qpos[qidx] = q_prev + t * (view.q - q_prev)
                hits = check(data)
                if hits:
                    view.q = None
                    view.reason = (f"the move from the previous view comes closer than "
                                   f"{check.clearance * 1e3:.0f} mm to {', '.join(hits[:3])} "
                                   f"({t:.0%} of the way)")
                    break
        if view.reachable:
            q_prev = view.q
    data.qpos[:] = saved
    mujoco.mj_forward(model, data)
