"""Closed-form inverse kinematics of a six-joint arm with a spherical wrist (the PUMA 560), the
rail angle given or searched.

The view plan asks for thousands of camera poses per configuration, most of them at the edge of
the workspace or beyond it; damped least squares spent up to 30 s per configuration there (a
target out of reach costs every restart). The arm's geometry answers directly: the wrist centre
fixes joints 1-3 (shoulder left or right, elbow up or down), the wrist's orientation joints 4-6
(flipped or not), eight solutions at most per rail angle, each checked against the joint limits.

The arm's DH table must have the PUMA's structure (:func:`supports`): twists (90, 0, -90, 90,
-90, 0) degrees, ``a1 = d1 = d2 = 0``, and a spherical wrist (``a4 = a5 = a6 = d5 = d6 = 0``);
its lengths ``a2, a3, d3, d4`` are read from the table. Angles follow the table's standard DH
convention, ``theta_i = q_i`` (pinocchio's model of :func:`sim.robot.load_arm_kinematics`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.robot.spec import ArmSpec

_TWISTS = (np.pi / 2, 0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, 0.0)
#: A solution is kept if forward kinematics puts the flange within this of the target (m, rad):
#: it guards against round-off at the workspace's boundary (the acos of 1 + 1e-16).
VERIFY_TOLERANCE = 1e-9
#: Below this sine of the wrist's middle angle (q5 near 0) joints 4 and 6 turn about one axis:
#: joint 4 keeps its reference value and joint 6 takes the rest.
WRIST_SINGULAR = 1e-9


def supports(spec: ArmSpec) -> bool:
    """The arm's DH table has the structure the closed form solves (see the module's text)."""
    dh = spec.dh
    if len(dh) != 6 or spec.urdf is not None:
        return False
    if any(abs(link.alpha - t) > 1e-12 for link, t in zip(dh, _TWISTS, strict=True)):
        return False
    zero = (dh[0].a, dh[0].d, dh[1].d, dh[3].a, dh[4].a, dh[5].a, dh[4].d, dh[5].d)
    return all(abs(v) < 1e-12 for v in zero)


@dataclass(frozen=True)
class Unreachable:
    """Why no solution exists, for the view plan's reasons."""

    reason: str


def _rz_ry(a, b):
    """``Rz(a) Ry(b)`` for arrays of angles : (n, 3, 3) float."""
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    z = np.zeros_like(a)
    return np.stack([np.stack([ca * cb, -sa, ca * sb], -1),
                     np.stack([sa * cb, ca, sa * sb], -1),
                     np.stack([-sb, z, cb], -1)], -2)


def _in_frame0(F0, T_world_flange):
    """The flange's origin (the wrist centre) in each DH frame 0 of ``F0`` : (n, 3) float."""
    return np.einsum("nji,nj->ni", F0[:, :3, :3], T_world_flange[:3, 3] - F0[:, :3, 3])


def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


class SphericalWristIK:
    """All solutions for a flange pose, for :class:`sim.robot.ArmKinematics` of a supported arm.

    Parameters
    ----------
    kin : sim.robot.ArmKinematics
        Its rail joint (index 0) carries DH frame 0; the arm joints follow.
    rail_step_deg : float
        Spacing of the rail angles searched when the rail is free.
    """

    def __init__(self, kin, rail_step_deg: float = 0.5):
        if not supports(kin.spec):
            raise ValueError(f"arm {kin.spec.name!r}: its DH table is not of the PUMA's structure; "
                             "use the numerical IK (ArmKinematics.solve_ik)")
        dh = kin.spec.dh
        self.kin = kin
        self.a2, self.a3, self.d3, self.d4 = dh[1].a, dh[2].a, dh[2].d, dh[3].d
        self.L = float(np.hypot(self.a3, self.d4))
        self.phi = float(np.arctan2(self.d4, self.a3))
        q = np.zeros(kin.nq)
        self.T_flange_camera = np.linalg.inv(kin.frame_pose(q, "flange")) @ kin.frame_pose(
            q, "camera")
        lo, hi = kin.lower[0], kin.upper[0]
        n = max(2, int(np.ceil((hi - lo) / np.deg2rad(rail_step_deg))) + 1)
        self.rail_grid = np.linspace(lo, hi, n)
        self._frame0_grid = np.array([self.frame0(r) for r in self.rail_grid])
        #: shoulder and elbow branch (0-3: shoulder sign x 2 + elbow sign) of the arm's home
        #: posture: the working posture a solve keeps where the view allows
        self.home_arm_branch = self._branch(np.r_[0.0, kin.spec.home])

    def _frame0s(self, rails):
        """DH frame 0 at each rail angle, from the grid's where they are the grid's."""
        idx = np.searchsorted(self.rail_grid, rails)
        idx = np.clip(idx, 0, len(self.rail_grid) - 1)
        if np.array_equal(self.rail_grid[idx], rails):
            return self._frame0_grid[idx]
        return np.array([self.frame0(r) for r in rails])

    def _branch(self, q) -> int:
        """The shoulder-and-elbow branch (index // 2 of :meth:`solutions`) of configuration
        ``q``."""
        T = self.kin.frame_pose(q, "flange")
        sols, valid = self.solutions(T, [q[0]], q)
        err = np.where(valid[0], np.max(np.abs(sols[0] - q), axis=1), np.inf)
        k = int(np.argmin(err))
        if not err[k] < 1e-6:
            raise ValueError(f"arm {self.kin.spec.name!r}: the closed form does not reproduce "
                             f"the configuration {np.round(q, 4).tolist()}; are its DH angles "
                             "offset, or the configuration outside the joint limits?")
        return k // 2

    def frame0(self, rail: float) -> np.ndarray:
        """DH frame 0 in the world at rail angle ``rail`` : (4, 4) float."""
        q = np.zeros(self.kin.nq)
        q[0] = rail
        return self.kin.frame_pose(q, "frame0")

    # ------------------------------------------------------------------------------------------
    def solutions(self, T_world_flange: np.ndarray, rails, reference) -> tuple[np.ndarray,
                                                                               np.ndarray]:
        """Every closed-form solution at each rail angle of ``rails``.

        Parameters
        ----------
        T_world_flange : (4, 4) float
            Target pose of DH frame 6.
        rails : (n,) float
            Rail angles (within the rail's limits).
        reference : (7,) float
            Configuration whose joints pick, for each joint, the whole turn of an angle nearest
            it (a joint may turn more than once within its limits), and joint 4 at the wrist's
            singularity.

        Returns
        -------
        q : (n, 8, 7) float
            Solutions (rail first); each joint the equivalent nearest ``reference`` within its
            limits.
        valid : (n, 8) bool
            The solution exists and every joint is within its limits.
        """
        rails = np.atleast_1d(np.asarray(rails, dtype=float))
        F0 = self._frame0s(rails)
        ref = np.asarray(reference, dtype=float)
        n = len(rails)
        R06 = np.einsum("nji,jk->nik", F0[:, :3, :3], T_world_flange[:3, :3])  # R0^T R_w6
        p = _in_frame0(F0, T_world_flange)
        q = np.full((n, 8, 7), np.nan)
        q[:, :, 0] = rails[:, None]
        valid = np.zeros((n, 8), dtype=bool)
        rho2 = p[:, 0] ** 2 + p[:, 1] ** 2 - self.d3 ** 2
        for s_shoulder, sh in enumerate((1.0, -1.0)):
            x = sh * np.sqrt(np.maximum(rho2, 0.0))
            q1 = np.arctan2(p[:, 1], p[:, 0]) - np.arctan2(-self.d3, x)
            y = p[:, 2]
            D = (x ** 2 + y ** 2 - self.a2 ** 2 - self.L ** 2) / (2.0 * self.a2 * self.L)
            ok_pos = (rho2 >= 0.0) & (np.abs(D) <= 1.0)
            for s_elbow, el in enumerate((1.0, -1.0)):
                t = el * np.arccos(np.clip(D, -1.0, 1.0))  # q3 + phi
                q3 = t - self.phi
                q2 = np.arctan2(y, x) - np.arctan2(self.L * np.sin(t), self.a2 + self.L * np.cos(t))
                R03 = _rz_ry(q1, -(q2 + q3))  # Rz(q1) Rx(90) Rz(q2 + q3) Rx(-90)
                R36 = np.einsum("nji,njk->nik", R03, R06)
                sb = np.hypot(R36[:, 0, 2], R36[:, 1, 2])
                for s_wrist, fl in enumerate((1.0, -1.0)):
                    k = 4 * s_shoulder + 2 * s_elbow + s_wrist
                    b = np.arctan2(fl * sb, R36[:, 2, 2])  # R36 = Rz(q4) Ry(-q5) Rz(q6)
                    sing = sb < WRIST_SINGULAR
                    safe = np.where(sing, 1.0, fl)
                    q4 = np.where(sing, ref[4],
                                  np.arctan2(safe * R36[:, 1, 2], safe * R36[:, 0, 2]))
                    q6 = np.where(sing, np.arctan2(R36[:, 1, 0], R36[:, 0, 0]) - q4,
                                  np.arctan2(safe * R36[:, 2, 1], -safe * R36[:, 2, 0]))
                    q[:, k, 1:] = np.stack([q1, q2, q3, q4, -b, q6], axis=1)
                    valid[:, k] = ok_pos
        q[:, :, 1:], inside = self._nearest_within_limits(q[:, :, 1:], ref[1:])
        valid &= inside
        return q, valid

    def _nearest_within_limits(self, q, ref):
        """Each angle turned by whole turns to lie within its limits nearest ``ref``; also
        whether every joint of a solution could be brought within its limits."""
        lo, hi = self.kin.lower[1:], self.kin.upper[1:]  # read now: a caller may narrow them
        base = _wrap(np.nan_to_num(q))
        turns = np.arange(-2, 3) * 2.0 * np.pi
        cand = base[..., None] + turns  # (..., 6, 5)
        ok = (cand >= lo[:, None] - 1e-12) & (cand <= hi[:, None] + 1e-12)
        dist = np.where(ok, np.abs(cand - ref[:, None]), np.inf)
        best = np.argmin(dist, axis=-1)
        out = np.take_along_axis(cand, best[..., None], axis=-1)[..., 0]
        out = np.clip(out, lo, hi)
        return out, ok.any(axis=-1).all(axis=-1)

    # ------------------------------------------------------------------------------------------
    def solve(self, T_world_camera: np.ndarray, rail: float, reference, *,
              free_rail: bool = True) -> np.ndarray | Unreachable:
        """The solution for a camera pose on the home posture's shoulder and elbow, with the
        smallest largest joint step from ``reference`` (rail included): at rail angle ``rail``
        or (``free_rail``) at any rail angle of the search grid.

        The arm keeps its home posture's shoulder and elbow (:attr:`home_arm_branch`, the
        working posture) wherever a solution on it exists; then the smallest step. The view
        plan passes the view's azimuth rail angle and the previous view's arm joints:
        along a ring the arm keeps its configuration and the rail turns (the stage is symmetric
        about the rail's axis), and where the azimuth's rail angle has no solution, or only one
        far from the last (another shoulder, elbow or wrist branch), the rail turns further
        instead of the arm swinging round. A large step is a long move, and the servos' lag
        along it what the straight line the plan checks does not hold.

        Returns
        -------
        q : (7,) float, or Unreachable with the reason
        """
        T_flange = np.asarray(T_world_camera, dtype=float) @ np.linalg.inv(self.T_flange_camera)
        ref = np.asarray(reference, dtype=float)
        rails = np.array([rail])
        if free_rail:
            rails = np.concatenate([rails, self._rails_within_reach(T_flange)])
        q, valid = self.solutions(T_flange, rails, ref)
        cand = q[valid]
        if len(cand):
            step = np.abs(cand - ref)
            other_arm = np.broadcast_to(np.arange(8) // 2 != self.home_arm_branch,
                                        valid.shape)[valid]
            order = np.lexsort((np.sum(step ** 2, axis=1), np.max(step, axis=1), other_arm))
            for c in cand[order]:
                if self._verify(c, T_flange):
                    return c
        return Unreachable(self._why(T_flange, rail, free_rail))

    def _rails_within_reach(self, T_flange):
        """The search grid's rail angles at which the wrist centre is within the arm's reach."""
        F0 = self._frame0_grid
        p = _in_frame0(F0, T_flange)
        rho2 = p[:, 0] ** 2 + p[:, 1] ** 2 - self.d3 ** 2
        D = (rho2 + p[:, 2] ** 2 - self.a2 ** 2 - self.L ** 2) / (2.0 * self.a2 * self.L)
        return self.rail_grid[(rho2 >= 0.0) & (np.abs(D) <= 1.0)]

    def _verify(self, q, T_flange) -> bool:
        T = self.kin.frame_pose(q, "flange")
        return (np.linalg.norm(T[:3, 3] - T_flange[:3, 3]) < VERIFY_TOLERANCE
                and np.linalg.norm(T[:3, :3] - T_flange[:3, :3]) < VERIFY_TOLERANCE)

    def _why(self, T_flange, rail, free_rail) -> str:
        F0 = self._frame0_grid if free_rail else np.array([self.frame0(rail)])
        p = _in_frame0(F0, T_flange)
        r = np.linalg.norm(p, axis=1)
        reach = float(np.hypot(self.d3, self.a2 + self.L))
        where = "at any rail angle" if free_rail else f"at rail {np.rad2deg(rail):.1f} deg"
        if r.min() > reach:
            return (f"out of reach {where}: the wrist centre is {r.min() * 1e3:.0f} mm from the "
                    f"shoulder, the arm reaches {reach * 1e3:.0f} mm")
        return f"no configuration within the joint limits {where}"
