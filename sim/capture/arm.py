"""The arm's motion during a capture: MuJoCo drives it with its position servos along the
straight joint-space line the view planner checked, and every physics step is watched for
contacts of the arm."""

from __future__ import annotations

import mujoco
import numpy as np

from sim import robot, views
from sim.capture_config import CaptureConfig

#: Peak of the minimum-jerk profile's speed, in units of (distance / duration): 15/8, a property
#: of the profile (:func:`min_jerk`), not a tunable; the tunables of the motion are fields of
#: :class:`~sim.capture.capture_config.CaptureConfig`.
MIN_JERK_PEAK_SPEED = 1.875


def min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk time scaling at ``tau`` in [0, 1]: the share of the way ``s`` and its first
    and second derivatives with respect to ``tau`` (zero speed and acceleration at both ends;
    peak speed 1.875 at 0.5)."""
    t = min(max(float(tau), 0.0), 1.0)
    return (t ** 3 * (10.0 - 15.0 * t + 6.0 * t * t),
            30.0 * t * t * (1.0 - 2.0 * t + t * t),
            60.0 * t * (1.0 - 3.0 * t + 2.0 * t * t))


def servo_gains(model: mujoco.MjModel, actuators) -> tuple[np.ndarray, np.ndarray]:
    """``(kp, kv)`` : two (n,) float of position servos (``gainprm[0] = kp``,
    ``biasprm = (0, -kp, -kv)``); raises ValueError for any other kind of actuator."""
    actuators = np.asarray(actuators, int)
    kp = model.actuator_gainprm[actuators, 0].copy()
    kv = -model.actuator_biasprm[actuators, 2]
    if np.any(kp <= 0) or np.any(np.abs(model.actuator_biasprm[actuators, 1] + kp) > 1e-9 * kp):
        names = [model.actuator(int(a)).name for a in actuators]
        raise ValueError(f"the arm's actuators {names} must be position servos (kp > 0, bias "
                         "-kp q - kv qdot); check the robot's <position> actuators")
    return kp, kv


def _as_slice(index: np.ndarray):
    """``index`` as a slice when it is a contiguous ascending run (numpy then takes a view),
    else unchanged."""
    index = np.asarray(index)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class Arm:
    """Moves the arm in MuJoCo with its position servos and watches what it touches.

    A move follows the straight joint-space line that the view planner checked
    (:func:`sim.views.check_paths`), on a minimum-jerk profile. A position servo (force
    ``kp (ctrl - q) - kv qdot``) fed only the reference lags it by ``(kv + damping) / kp`` times
    the speed -- the rail's servo (1 Hz, for 110 kg m^2) by 0.3 s, the arm's by 0.04-0.08 s -- so
    the rail trails the wrist and the executed path leaves the checked line (by 0.3 rad on the
    rail at 1 rad/s, measured). The command therefore carries the torque the reference motion
    needs (inverse dynamics at the reference position, speed and acceleration: inertia, the
    coupling of the arm's motion into the rail, gravity, damping) plus the servo's own damping:
    computed-torque feed-forward through the position servo,
    ``ctrl = q_ref + (tau_ref + kv v_ref) / kp``. The arm also holds its targets without sag.
    :attr:`max_path_deviation` records how far each joint strayed from the line. ``config``
    gives the peak speed of a move and when the arm has settled.
    """

    def __init__(self, model, data, kin, config: CaptureConfig = CaptureConfig()):
        self.model, self.data, self.kin, self.config = model, data, kin, config
        self.qidx = robot.qpos_indices(model, kin)
        self.vidx = np.array([model.jnt_dofadr[mujoco.mj_name2id(
            model, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in kin.joint_names])
        self.aidx = robot.actuator_indices(model, kin)
        self.links = views.arm_link_bodies(model, kin)
        #: geoms of the arm links, to test every physics step's contacts cheaply
        self.arm_geom = np.isin(model.geom_bodyid, sorted(self.links))
        self.kp, self.kv = servo_gains(model, self.aidx)
        #: joints whose actuators already carry the gravity compensation of their bodies
        #: (MuJoCo's actuatorgravcomp): that share of the inverse dynamics is not the servo's
        self.actuator_gravcomp = model.jnt_actgravcomp[[
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in kin.joint_names]]
        #: scratch data for the inverse dynamics of the reference
        self._inverse = mujoco.MjData(model)
        # views of the arrays touched at every physics step, and the joints' addresses as
        # slices where they are contiguous (a move is ~250 steps; numpy's per-call overhead on
        # these 6-vectors was most of its CPU besides mj_step and mj_inverse)
        self._iq, self._iv, self._ia = (_as_slice(i) for i in (self.qidx, self.vidx, self.aidx))
        self._qpos, self._qvel, self._ctrl = data.qpos, data.qvel, data.ctrl
        inv = self._inverse
        self._inv_qpos, self._inv_qvel, self._inv_qacc = inv.qpos, inv.qvel, inv.qacc
        self._inv_frc, self._inv_grav = inv.qfrc_inverse, inv.qfrc_gravcomp
        #: the joint values the arm was last sent to (None: wherever it stands)
        self.target: np.ndarray | None = None
        #: largest distance (rad or m) of each joint from the planned line, over all moves
        self.max_path_deviation = np.zeros(len(self.qidx))

    def command(self, q_ref, v_ref=None, a_ref=None) -> np.ndarray:
        """Servo targets that make the arm follow ``q_ref`` with speed ``v_ref`` and
        acceleration ``a_ref`` (default 0: hold ``q_ref``) : (n,) float."""
        iv = self._iv
        v_ref = np.zeros(len(self.qidx)) if v_ref is None else v_ref
        np.copyto(self._inv_qpos, self._qpos)
        self._inv_qpos[self._iq] = q_ref
        self._inv_qvel.fill(0.0)
        self._inv_qvel[iv] = v_ref
        self._inv_qacc.fill(0.0)
        if a_ref is not None:
            self._inv_qacc[iv] = a_ref
        mujoco.mj_inverse(self.model, self._inverse)
        tau = self._inv_frc[iv] - self.actuator_gravcomp * self._inv_grav[iv]
        return q_ref + (tau + self.kv * v_ref) / self.kp

    def place(self, q):
        """Start the arm at ``q`` (the robot's initial pose), at rest and held there."""
        q = np.asarray(q, dtype=float)
        self.data.qpos[self.qidx] = q
        self.data.qvel[:] = 0.0
        self.target = q.copy()
        self.data.ctrl[self.aidx] = self.command(q)
        mujoco.mj_forward(self.model, self.data)

    def _step(self, hits: set[str]) -> None:
        """One physics step; contacts of the arm links (with anything) go into ``hits``."""
        m, d = self.model, self.data
        mujoco.mj_step(m, d)
        if d.ncon and self.arm_geom[d.contact.geom[: d.ncon]].any():
            hits.update(views.arm_collisions(m, d, self.links))

    def move(self, q) -> list[str]:
        """Drive along the straight joint-space line from the last target to ``q``, then settle;
        returns the contacts of the arm met at any physics step on the way."""
        m, d = self.model, self.data
        dt = m.opt.timestep
        q = np.asarray(q, dtype=float)
        q0 = d.qpos[self.qidx].copy() if self.target is None else self.target
        dq = q - q0
        steps = max(1, int(np.ceil(MIN_JERK_PEAK_SPEED * float(np.max(np.abs(dq)))
                                   / self.config.move_speed / dt)))
        duration = steps * dt
        hits: set[str] = set()
        deviation = np.zeros(len(self.qidx))
        qpos, ctrl, iq, ia = self._qpos, self._ctrl, self._iq, self._ia
        # the reference of every step at once: per element the same products and sums as one
        # step at a time (q0 + s dq, ds / T dq, dds / T**2 dq)
        s, ds, dds = (np.array(c) for c in zip(*(min_jerk(i / steps)
                                                  for i in range(1, steps + 1)), strict=True))
        q_refs = q0 + s[:, None] * dq
        v_refs = (ds / duration)[:, None] * dq
        a_refs = (dds / duration ** 2)[:, None] * dq
        for q_ref, v_ref, a_ref in zip(q_refs, v_refs, a_refs, strict=True):
            ctrl[ia] = self.command(q_ref, v_ref, a_ref)
            self._step(hits)
            np.maximum(deviation, np.abs(qpos[iq] - q_ref), out=deviation)
        self.target = q.copy()
        ctrl[ia] = self.command(q)
        qvel, iv, settled = self._qvel, self._iv, self.config.settle_speed
        for _ in range(int(self.config.settle_max_time / dt)):
            self._step(hits)
            if np.max(np.abs(qvel[iv])) < settled:
                break
        mujoco.mj_forward(m, d)
        hits.update(views.arm_collisions(m, d, self.links))
        self.max_path_deviation = np.maximum(self.max_path_deviation, deviation)
        return sorted(hits)

    def measured_q(self) -> np.ndarray:
        return self.data.qpos[self.qidx].copy()
