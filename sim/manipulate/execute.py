"""Executing a plan in MuJoCo physics, with a gripper that can fail.

The arm's position servos follow the plan (travel to the pre-grasp pose, the straight approach,
then the motion waypoints on a minimum-jerk time law) with computed-torque feed-forward (the arm's
own inverse dynamics, as in :mod:`sim.capture`, without contacts: the feed-forward is what the arm
needs to move itself, never a push into what it touches), so it tracks the planned path instead
of lagging behind it.

The gripper: the PUMA's is a fixed two-finger shape without actuated fingers, so a grasp is a
MuJoCo ``<equality><weld>`` between the flange and the body under the fingertips, switched on
once the grasp frame is within ``activation_distance`` of its planned pose. It is not a weld of
unlimited strength: every physics step reads the weld's constraint force and torque, and when
either exceeds the grip's limit (:class:`GripConfig`) the weld lets go, as fingers would slip.
An arm that follows a wrong axis drags the object against its joint: the forces grow until the
grasp breaks, and the object stops short. The result reports the peak and RMS force and torque
along the path and where the grasp was lost.

What moved is measured as physics sees it: the object's joint values before and after
(:attr:`ManipulationResult.joints_before`, ``joints_after``). Which of them is "the" joint, and
how far it should have moved, is scoring's business (:func:`achieved_along`), not the robot's.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import asdict, dataclass, field

import mujoco
import numpy as np

from sim.capture import servo_gains
from sim.manipulate.estimate import GraspMissed, JointEstimate, ManipulationError
from sim.manipulate.planning import Plan
from sim.manipulate.world import World, body_pose, fresh_data, object_joint_values

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GripConfig:
    """The gripper and the motion's timing."""

    max_force_n: float = 60.0
    """grip strength: the weld lets go when its force exceeds this (N). A parallel gripper with
    ~100 N of finger force and rubber pads (friction ~0.6) holds about 60 N against slipping."""
    max_torque_nm: float = 3.0
    """... or its torque this (N m): 60 N at the ~5 cm between the finger pads"""
    activation_distance: float = 0.005
    """the weld is switched on when the grasp frame is this close to its planned pose (m)"""
    reach_margin: float = 0.01
    """the ray from the grasp frame along the approach must hit a body within the standoff plus
    this (m)"""
    motion_speed: float = 0.04
    """average speed of the grasp point during the motion (m/s; minimum-jerk peaks at 1.9x)"""
    min_motion_time: float = 1.5
    """shortest motion (s)"""
    travel_speed: float = 1.0
    """joint-space travel speed to the pre-grasp pose (rad/s)"""
    travel_resample: float = 0.05
    """a travel by the home posture is followed through waypoints this far apart (rad)"""
    approach_time: float = 0.8
    """pre-grasp to grasp (s)"""
    settle_speed: float = 1e-3
    """settled when joint speeds fall below this (rad/s) ..."""
    settle_max_time: float = 1.0
    """... or after this long (s)"""
    hold_time: float = 0.3
    """hold with the weld on after the motion (s)"""
    release_time: float = 0.3
    """settle after letting go (s)"""


@dataclass
class ManipulationResult:
    """What one manipulation did, measured in the simulation (SI units; degrees/mm in to_dict)."""

    scene: str
    estimate: dict
    """the joint the arm followed: type, axis, point, source, name"""
    requested: float
    """requested displacement (rad or m) about/along the estimate"""
    grasp_point: list
    grasp_normal: list
    grasp_hidden: bool
    grasp_visibility: str
    grasp_body: str
    """the body the weld held (physics: what was under the fingertips)"""
    grasp_roll_deg: float
    peak_force: float
    """peak norm of the weld's constraint force (N) during motion and hold"""
    rms_force: float
    """RMS of that force over the motion and hold (N)"""
    peak_torque: float
    """peak norm of the weld's constraint torque (N m)"""
    grasp_lost: bool
    """the weld let go because its force or torque exceeded the grip's limit"""
    grasp_lost_at: float | None
    """the share of the motion done when it let go (None: held to the end)"""
    grip_limits: dict
    """``{"force_n", "torque_nm"}``: the grip's limits"""
    tracking_rms: float
    """RMS of actual minus commanded arm joint angles during the motion (rad)"""
    tracking_max: float
    path_error_max: float
    """largest distance of the grasp frame from its planned path during the motion (m)"""
    arm_contacts: list
    simulated_time: float
    motion_duration: float
    """duration of the motion along the estimate (s)"""
    joints_before: dict
    """object joint values when the motion started (physics)"""
    joints_after: dict
    """... and after the release"""
    candidates: dict
    planned_in: str
    """the world the plan was made in (``"registered model"`` in the harness)"""
    q_start: list = field(default_factory=list)
    """the arm's configuration the run started from (rad, rail first)"""
    approach: list = field(default_factory=list)
    """the plan's arm waypoints from the pre-grasp pose to the grasp pose (rad): the arm's
    configuration at the grasp is the last (scoring's force reference replays them)"""
    travel: list = field(default_factory=list)
    """the plan's waypoints from the start to the pre-grasp pose when it went by the home
    posture (empty: the straight line)"""
    log: list = field(default_factory=list)
    frames: list = field(default_factory=list, repr=False)
    """(time, phase, qpos copy) snapshots, if recording was asked for"""

    def displacement(self, joint: str) -> float:
        """How far object joint ``joint`` moved (rad or m, its own sense)."""
        return self.joints_after[joint] - self.joints_before[joint]

    def to_dict(self) -> dict:
        d = asdict(self)
        d.pop("frames")
        d["tracking_rms_deg"] = float(np.rad2deg(self.tracking_rms))
        d["tracking_max_deg"] = float(np.rad2deg(self.tracking_max))
        d["path_error_max_mm"] = 1e3 * self.path_error_max
        return d


def achieved_along(result: ManipulationResult, joint_type: str, joint_axis, joint_name: str
                   ) -> float:
    """The displacement of the true joint ``joint_name`` in the sense of the estimate the arm
    followed (scoring: the true joint is the answer key's). A true axis pointing against the
    estimated one counts the other way round."""
    raw = result.displacement(joint_name)
    est_axis = np.asarray(result.estimate["axis"], float)
    same = joint_type != result.estimate["type"] or float(np.dot(joint_axis, est_axis)) >= 0
    return raw if same else -raw


def _min_jerk(tau: float) -> tuple[float, float, float]:
    """Position, velocity and acceleration of the minimum-jerk profile at ``tau`` in [0, 1]."""
    t = min(max(tau, 0.0), 1.0)
    return (t ** 3 * (10 - 15 * t + 6 * t * t), 30 * t * t * (1 - 2 * t + t * t),
            60 * t * (1 - 3 * t + 2 * t * t))


class _Run:
    """The physics run: servo commands with feed-forward, the weld and its forces."""

    def __init__(self, world: World, data, grip: GripConfig, record_every: float | None):
        self.w, self.d, self.grip = world, data, grip
        self.dt = world.model.opt.timestep
        self.record_every = record_every
        self.frames: list = []
        self._next_rec = 0.0
        self.weld: int | None = None
        self.forces: list = []
        self.contacts: set = set()
        self.lost_at: float | None = None
        self.kp, self.kv = servo_gains(world.model, world.aidx)
        gid = [mujoco.mj_name2id(world.model, mujoco.mjtObj.mjOBJ_JOINT, n)
               for n in world.kin.joint_names]
        self.gravcomp = world.model.jnt_actgravcomp[gid]
        # the feed-forward's model: the arm's own dynamics, no contacts and no welds (mj_inverse
        # with contacts turns a fingertip grazing the object at the commanded pose into a
        # feed-forward torque that pushes into it)
        self._inv_model = copy.copy(world.model)
        self._inv_model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT
                                                | mujoco.mjtDisableBit.mjDSBL_EQUALITY)
        self._inv = mujoco.MjData(self._inv_model)

    def command(self, q_ref, v_ref=None, a_ref=None) -> np.ndarray:
        """Servo targets that make the arm follow ``q_ref`` at ``v_ref``, ``a_ref``:
        ``q_ref + (tau_ref + kv v_ref) / kp`` with ``tau_ref`` the arm's inverse dynamics."""
        w, inv = self.w, self._inv
        n = len(w.qidx)
        v_ref = np.zeros(n) if v_ref is None else v_ref
        inv.qpos[:] = self.d.qpos
        inv.qpos[w.qidx] = q_ref
        inv.qvel[:] = 0.0
        inv.qvel[w.vidx] = v_ref
        inv.qacc[:] = 0.0
        if a_ref is not None:
            inv.qacc[w.vidx] = a_ref
        inv.eq_active[:] = 0
        mujoco.mj_inverse(self._inv_model, inv)
        tau = inv.qfrc_inverse[w.vidx] - self.gravcomp * inv.qfrc_gravcomp[w.vidx]
        return q_ref + (tau + self.kv * v_ref) / self.kp

    def step(self, phase: str, progress: float | None = None):
        m, d = self.w.model, self.d
        mujoco.mj_step(m, d)
        if self.weld is not None:
            rows = np.flatnonzero((d.efc_type[:d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
                                  & (d.efc_id[:d.nefc] == self.weld))
            f = d.efc_force[rows]
            if len(f) == 6:
                force, torque = float(np.linalg.norm(f[:3])), float(np.linalg.norm(f[3:]))
                self.forces.append((phase, force, torque))
                if force > self.grip.max_force_n or torque > self.grip.max_torque_nm:
                    d.eq_active[self.weld] = 0  # the fingers slip: the grasp is lost
                    self.weld = None
                    self.lost_at = 1.0 if progress is None else progress
                    log.info("grasp lost in %s (%.0f%% of the motion): %.1f N, %.2f N m over "
                             "the grip's %.0f N / %.1f N m", phase, 100 * self.lost_at, force,
                             torque, self.grip.max_force_n, self.grip.max_torque_nm)
        if self.record_every is not None and d.time >= self._next_rec:
            self.frames.append((float(d.time), phase, d.qpos.copy()))
            self._next_rec = d.time + self.record_every

    def check_contacts(self):
        """Record arm contacts, except the gripper with the body it holds."""
        m, d = self.w.model, self.d
        held = None if self.weld is None else int(m.eq_obj2id[self.weld])
        for c in d.contact[: d.ncon]:
            b = {int(m.geom_bodyid[c.geom[0]]), int(m.geom_bodyid[c.geom[1]])}
            if not b & self.w.arm_links or (held is not None and b == {self.w.flange_body, held}):
                continue
            names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or f"geom{int(g)}"
                     for g in c.geom]
            self.contacts.add("/".join(sorted(names)))

    def settle(self, phase: str):
        for _ in range(int(self.grip.settle_max_time / self.dt)):
            self.step(phase)
            if np.max(np.abs(self.d.qvel[self.w.vidx])) < self.grip.settle_speed:
                break

    def follow(self, q_points: np.ndarray, duration: float, phase: str):
        """Along joint waypoints (uniform in path parameter) on a minimum-jerk law."""
        n = len(q_points) - 1
        steps = max(1, int(np.ceil(duration / self.dt)))
        for i in range(1, steps + 1):
            s, ds, dds = _min_jerk(i / steps)
            x = s * n
            k = min(int(x), n - 1)
            dq = q_points[k + 1] - q_points[k]
            q = q_points[k] + (x - k) * dq
            self.d.ctrl[self.w.aidx] = self.command(q, ds * n / duration * dq,
                                                    dds * n / duration ** 2 * dq)
            self.step(phase)
            if i % 25 == 0:
                self.check_contacts()


def even_path(q_points: np.ndarray, step: float) -> np.ndarray:
    """Joint waypoints along the straight lines through ``q_points``, at most ``step`` (rad) apart
    in any joint and evenly spaced along each line; the given waypoints kept."""
    out = [q_points[0]]
    for a, b in zip(q_points[:-1], q_points[1:], strict=True):
        n = max(1, int(np.ceil(float(np.max(np.abs(b - a))) / step)))
        out += [a + (b - a) * k / n for k in range(1, n + 1)]
    return np.array(out)


def execute(world: World, plan: Plan, estimate: JointEstimate, amount: float, q_start, *,
            candidates_summary: dict | None = None, planned_in: str = "",
            grip: GripConfig = GripConfig(), record_every: float | None = None,
            physics: _Run | None = None) -> ManipulationResult:
    """Run ``plan`` in physics from ``q_start``: travel, approach, grasp, motion, hold, release.

    ``physics``: go on in the physics of an earlier attempt (:attr:`GraspMissed.physics`, the
    arm back at ``q_start``) instead of a fresh world: what that attempt touched stays touched.

    Raises
    ------
    ManipulationError
        The gripper did not arrive at the grasp pose, or the fingertips touch a body that is
        not the object's.
    GraspMissed
        Nothing of the object is under the fingertips at the grasp pose (a ManipulationError):
        the arm has backed out the way it came, to ``q_start``, in the physics the exception
        holds.
    """
    m, kin = world.model, world.kin
    messages: list[str] = []

    def say(msg, *args):
        text = msg % args if args else msg
        log.info(text)
        messages.append(text)

    q_start = kin.clip(np.asarray(q_start, float))
    if physics is None:
        data = fresh_data(world, q_start)
        run = _Run(world, data, grip, record_every)
        run.d.ctrl[world.aidx] = run.command(q_start)
    else:
        run, data = physics, physics.d
    if plan.travel is not None and np.allclose(plan.travel[0], q_start, atol=1e-6):
        # by the home posture: waypoints evenly spaced, so that follow's speed is even
        path = even_path(np.asarray(plan.travel, float), grip.travel_resample)
    else:
        path = np.array([q_start, plan.q_pre])
    travel = max(0.5, float(np.sum(np.abs(np.diff(path, axis=0)).max(axis=1)))
                 / grip.travel_speed)
    run.follow(path, travel, "travel")
    run.settle("travel")
    run.follow(plan.approach, grip.approach_time, "approach")
    run.settle("approach")
    mujoco.mj_forward(m, data)
    T_now = kin.frame_pose(data.qpos[world.qidx], "grasp")
    miss = float(np.linalg.norm(T_now[:3, 3] - plan.T_grasp[:3, 3]))
    if miss > grip.activation_distance:
        raise ManipulationError(f"the gripper stopped {1e3 * miss:.1f} mm from the grasp pose "
                                f"(more than {1e3 * grip.activation_distance:.0f} mm): no grasp")
    geomid = np.zeros(1, dtype=np.int32)
    groups = np.zeros(6, dtype=np.uint8)
    groups[3] = 1
    standoff = float(np.linalg.norm(plan.T_grasp[:3, 3] - plan.candidate.point))
    hit = mujoco.mj_ray(m, data, T_now[:3, 3], T_now[:3, 2], groups, 1, world.flange_body, geomid)
    if hit < 0 or hit > standoff + grip.reach_margin:
        run.check_contacts()
        touched = sorted(run.contacts)
        # the fingers closed on nothing: the arm backs out the way it came, to q_start
        run.follow(np.asarray(plan.approach, float)[::-1], grip.approach_time, "retreat")
        run.follow(path[::-1], travel, "retreat")
        run.settle("retreat")
        raise GraspMissed(
            f"nothing under the fingertips at {np.round(plan.candidate.point, 3).tolist()} (ray "
            f"{'missed' if hit < 0 else f'hit at {hit:.3f} m'}): the model's surface is not "
            "where the object is" + (f"; on its way the arm touched {', '.join(touched[:3])}"
                                     if touched else ""), plan.candidate.point, run)
    body = int(m.geom_bodyid[int(geomid[0])])
    if body not in world.weld_of_body:
        raise ManipulationError(f"the fingertips touch {m.body(body).name!r}, which is not part "
                                "of the object")
    eq = world.weld_of_body[body]
    anchor_w = T_now[:3, 3] + hit * T_now[:3, 2]
    T1, T2 = body_pose(data, world.flange_body), body_pose(data, body)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (T1[:3, :3].T @ T2[:3, :3]).reshape(-1))
    m.eq_data[eq, 0:3] = T2[:3, :3].T @ (anchor_w - T2[:3, 3])
    m.eq_data[eq, 3:6] = T1[:3, :3].T @ (anchor_w - T1[:3, 3])
    m.eq_data[eq, 6:10] = quat
    data.eq_active[eq] = 1
    run.weld = eq
    say("grasp: weld on between the flange and %r at %s (%.1f mm from the plan)",
        m.body(body).name, np.round(anchor_w, 3).tolist(), 1e3 * miss)
    before = object_joint_values(world, data)

    if estimate.type == "revolute":
        length = abs(amount) * float(np.linalg.norm(np.cross(
            estimate.axis, plan.T_grasp[:3, 3] - estimate.point)))
    else:
        length = abs(amount)
    duration = max(grip.min_motion_time, length / grip.motion_speed)
    n = len(plan.q_path) - 1
    steps = int(np.ceil(duration / run.dt))
    errs, path_err = [], 0.0
    for i in range(1, steps + 1):
        s, ds, dds = _min_jerk(i / steps)
        x = s * n
        k = min(int(x), n - 1)
        f = x - k
        dq = plan.q_path[k + 1] - plan.q_path[k]
        q_cmd = plan.q_path[k] + f * dq
        data.ctrl[world.aidx] = run.command(q_cmd, ds * n / duration * dq,
                                            dds * n / duration ** 2 * dq)
        run.step("motion", progress=s)
        errs.append(data.qpos[world.qidx] - q_cmd)
        if i % 10 == 0 and run.weld is not None:
            p_plan = plan.p_path[k] + f * (plan.p_path[k + 1] - plan.p_path[k])
            p_now = kin.frame_pose(data.qpos[world.qidx], "grasp")[:3, 3]
            path_err = max(path_err, float(np.linalg.norm(p_now - p_plan)))
        if i % 25 == 0:
            run.check_contacts()
    for _ in range(int(grip.hold_time / run.dt)):
        run.step("hold")
    if run.weld is not None:
        data.eq_active[eq] = 0
        run.weld = None
    for _ in range(int(grip.release_time / run.dt)):
        run.step("release")
    mujoco.mj_forward(m, data)
    after = object_joint_values(world, data)
    errs = np.array(errs)
    f_all = np.array([(fo, to) for _, fo, to in run.forces]) if run.forces else np.zeros((1, 2))
    if run.lost_at is not None:
        say("the grasp was LOST at %.0f%% of the motion: the weld's force exceeded the grip "
            "(%.0f N / %.1f N m)", 100 * run.lost_at, grip.max_force_n, grip.max_torque_nm)
    if run.contacts:
        say("arm contacts during the run: %s", sorted(run.contacts)[:6])
    c = plan.candidate
    result = ManipulationResult(
        scene=world.name,
        estimate={"type": estimate.type, "axis": estimate.axis.tolist(),
                  "point": estimate.point.tolist(), "source": estimate.source,
                  "name": estimate.name},
        requested=float(amount), grasp_point=c.point.tolist(), grasp_normal=c.normal.tolist(),
        grasp_hidden=bool(c.hidden), grasp_visibility=c.visibility, grasp_body=m.body(body).name,
        grasp_roll_deg=plan.roll_deg, peak_force=float(f_all[:, 0].max()),
        rms_force=float(np.sqrt(np.mean(f_all[:, 0] ** 2))),
        peak_torque=float(f_all[:, 1].max()), grasp_lost=run.lost_at is not None,
        grasp_lost_at=run.lost_at,
        grip_limits={"force_n": grip.max_force_n, "torque_nm": grip.max_torque_nm},
        tracking_rms=float(np.sqrt(np.mean(errs ** 2))), tracking_max=float(np.abs(errs).max()),
        path_error_max=path_err, arm_contacts=sorted(run.contacts),
        simulated_time=float(data.time), motion_duration=float(duration),
        joints_before=before, joints_after=after,
        candidates=candidates_summary or {}, planned_in=planned_in,
        q_start=[float(x) for x in q_start],
        approach=[[float(x) for x in qk] for qk in plan.approach], log=messages,
        travel=[] if plan.travel is None else [[float(x) for x in qk] for qk in plan.travel],
        frames=run.frames)
    say("%s: requested %.4g along the %s estimate; peak weld force %.1f N (rms %.1f), torque "
        "%.2f N m; tracking max %.2f deg, grasp path error max %.1f mm", world.name, amount,
        estimate.type, result.peak_force, result.rms_force, result.peak_torque,
        np.rad2deg(result.tracking_max), 1e3 * result.path_error_max)
    result.log = messages
    return result
