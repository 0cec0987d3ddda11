"""The records of a loaded scene: :class:`Scene` (the compiled model and the ground truth of its
object), its :class:`Link`, :class:`Joint` and :class:`Coupling`, and :class:`SceneError`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from sim.scene.holds import add_joint_holds, hold_joints

#: Names of the two configurations.
CONFIGURATIONS = ("a", "b")

#: A joint whose two configuration values differ by no more than this did not move between the
#: configurations (it is "static"; the reconstruction must not invent it). Values are written in
#: decimal in the XML, so only a representation error is forgiven, as for RANGE_TOLERANCE.
STATIC_TOLERANCE = 1e-9


class SceneError(ValueError):
    """A scene file is missing, does not compile, or breaks the scene conventions."""


@dataclass(frozen=True)
class Link:
    """A rigid link of the object.

    Attributes
    ----------
    name : str
        Name of the link's root body (``"object"`` for the base link).
    body_ids : tuple of int
        Ids of every MuJoCo body of the link, its root first.
    body_names : tuple of str
        Their names (a nameless body shows as ``""``).
    """

    name: str
    body_ids: tuple[int, ...]
    body_names: tuple[str, ...]

    @property
    def body_id(self) -> int:
        """Id of the link's root body."""
        return self.body_ids[0]


@dataclass(frozen=True, eq=False)
class Joint:
    """Ground truth of one object joint.

    Attributes
    ----------
    name : str
        MuJoCo joint name.
    type : str
        ``"revolute"`` (MuJoCo hinge) or ``"prismatic"`` (MuJoCo slide).
    joint_id, qpos_adr, dof_adr : int
        Indices into the compiled model.
    axis : (3,) float
        Unit axis direction in the world frame at configuration A (positive joint values turn
        the child right-handed about it / move the child along it).
    point : (3,) float
        A point on the axis in the world frame at configuration A (the joint's anchor; for a
        prismatic joint any point of the line is as good as this one).
    parent, child : str
        Names of the parent link (``"world"`` if the object's root itself moves) and child link.
    range : (2,) float
        Joint limits (rad or m).
    value_a, value_b : float
        Joint values in configurations A and B (rad or m).
    """

    name: str
    type: str
    joint_id: int
    qpos_adr: int
    dof_adr: int
    axis: np.ndarray
    point: np.ndarray
    parent: str
    child: str
    range: np.ndarray
    value_a: float
    value_b: float

    def value(self, configuration: str) -> float:
        """Joint value in configuration ``"a"`` or ``"b"``."""
        return self.value_a if _check_configuration(configuration) == "a" else self.value_b

    @property
    def motion(self) -> float:
        """``value_b - value_a``: the joint's motion between the configurations (rad or m)."""
        return self.value_b - self.value_a

    @property
    def static(self) -> bool:
        """True if the joint did not move between the configurations (``|motion|`` at most
        :data:`STATIC_TOLERANCE`): no relative motion of its child link to find."""
        return abs(self.motion) <= STATIC_TOLERANCE


@dataclass(frozen=True)
class Coupling:
    """Two object joints that move together (a MuJoCo ``<equality><joint>`` constraint):
    ``joint1 = c0 + c1 q2 + c2 q2^2 + c3 q2^3 + c4 q2^4`` with ``q2`` the value of ``joint2``.

    Attributes
    ----------
    name : str
        Name of the equality constraint (``""`` if it has none).
    joint1, joint2 : str
        The driven and the driving joint.
    polycoef : (5,) float
        ``c0 .. c4``.
    """

    name: str
    joint1: str
    joint2: str
    polycoef: tuple[float, ...]

    def value(self, q2: float) -> float:
        """``joint1``'s value implied by ``joint2`` at ``q2``."""
        return float(sum(c * q2 ** k for k, c in enumerate(self.polycoef)))


@dataclass(frozen=True, eq=False)
class Scene:
    """A compiled scene and the ground truth of its object.

    Attributes
    ----------
    name : str
        Scene name (file stem).
    path : pathlib.Path
        Absolute path of the scene file.
    model : mujoco.MjModel
        The compiled model (stage, arm and object).
    links : tuple of Link
        The object's links, base link (``"object"``) first, then in body order.
    joints : tuple of Joint
        The object's joints in model order.
    couplings : tuple of Coupling
        Pairs of object joints constrained to move together (empty for independent joints).
    reconstruct_settings : dict
        ``{"stage.field": value}``: the reconstruction settings the scene asks for (see the
        module docstring; artrecon.reconstruct.with_settings), empty for the defaults.
    """

    name: str
    path: Path
    model: mujoco.MjModel
    links: tuple[Link, ...]
    joints: tuple[Joint, ...]
    couplings: tuple[Coupling, ...] = ()
    reconstruct_settings: Mapping[str, float] = field(default_factory=dict)

    def joint_values(self, data: mujoco.MjData) -> dict[str, float]:
        """Joint values ``{joint name: value}`` of the object in ``data``."""
        return {j.name: float(data.qpos[j.qpos_adr]) for j in self.joints}

    @property
    def moving_joints(self) -> tuple[Joint, ...]:
        """The joints that move between the configurations (not :attr:`Joint.static`)."""
        return tuple(j for j in self.joints if not j.static)

    def joint(self, name: str) -> Joint:
        """The object joint called ``name``."""
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"scene {self.name!r} has no object joint {name!r}; "
                       f"its joints are {[j.name for j in self.joints]}")

    def link(self, name: str) -> Link:
        """The object link whose root body is called ``name``."""
        for li in self.links:
            if li.name == name:
                return li
        raise KeyError(f"scene {self.name!r} has no object link {name!r}; "
                       f"its links are {[li.name for li in self.links]}")

    def configuration(self, configuration: str) -> dict[str, float]:
        """Joint values ``{joint name: value}`` of configuration ``"a"`` or ``"b"``."""
        return {j.name: j.value(configuration) for j in self.joints}

    def set_configuration(self, data: mujoco.MjData, configuration: str,
                          forward: bool = True) -> None:
        """Put the object of ``data`` in configuration ``"a"`` or ``"b"``.

        Sets the object joints' positions (and zeroes their velocities); the arm and rail are
        left as they are. With ``forward`` runs ``mj_forward`` so poses are up to date.
        """
        self.set_joint_values(data, self.configuration(configuration), forward=forward)

    def set_joint_values(self, data: mujoco.MjData, values: Mapping[str, float],
                         forward: bool = True) -> None:
        """Set object joints ``{name: value}`` in ``data`` (others unchanged), zero their
        velocities and, with ``forward``, run ``mj_forward``."""
        if data.qpos.shape != (self.model.nq,):
            raise ValueError(f"expected MjData of this scene's model with qpos of shape "
                             f"({self.model.nq},), got {data.qpos.shape}")
        for name, value in values.items():
            j = self.joint(name)
            data.qpos[j.qpos_adr] = float(value)
            data.qvel[j.dof_adr] = 0.0
        if forward:
            mujoco.mj_forward(self.model, data)

    def make_data(self, configuration: str = "a") -> mujoco.MjData:
        """A fresh ``MjData``: the model's first keyframe if it has one (the arm's ``home``,
        with its controls), else ``qpos0``; the object in ``configuration``; forwarded."""
        data = mujoco.MjData(self.model)
        if self.model.nkey > 0:
            mujoco.mj_resetDataKeyframe(self.model, data, 0)
        self.set_configuration(data, configuration)
        return data

    def link_poses(self, configuration: str) -> dict[str, np.ndarray]:
        """World poses ``{link name: T_world_link (4, 4)}`` of the links' root bodies in
        configuration ``"a"`` or ``"b"`` (arm at its keyframe; it does not move the object)."""
        data = self.make_data(configuration)
        poses = {}
        for li in self.links:
            T = np.eye(4)
            T[:3, :3] = data.xmat[li.body_id].reshape(3, 3)
            T[:3, 3] = data.xpos[li.body_id]
            poses[li.name] = T
        return poses

    @property
    def held_joints(self) -> tuple[str, ...]:
        """Names of the joints :meth:`with_joint_holds` holds: every object joint except those a
        coupling drives (its ``joint1``; the coupling already ties it to a held joint)."""
        driven = {c.joint1 for c in self.couplings}
        return tuple(j.name for j in self.joints if j.name not in driven)

    def with_joint_holds(self) -> Scene:
        """The same scene compiled with an inactive hold on each of :attr:`held_joints`.

        The returned scene's model has the same bodies, joints and geoms (same ids and
        addresses) and one more equality constraint per held joint (:func:`add_joint_holds`);
        switch the holds on with :meth:`hold`. The model is compiled anew from the file: it
        is the caller's own (:func:`hold_joints` writes the held values into it).
        """
        spec = mujoco.MjSpec.from_file(str(self.path))
        add_joint_holds(spec, self.held_joints)
        try:
            model = spec.compile()
        except ValueError as err:
            raise SceneError(f"{self.path}: MuJoCo could not compile the scene with joint "
                             f"holds: {err}") from err
        if (model.nq, model.nbody, model.ngeom, model.njnt) != (
                self.model.nq, self.model.nbody, self.model.ngeom, self.model.njnt):
            raise SceneError(f"{self.path}: adding the joint holds changed the model's layout; "
                             "report this bug (sim/scene/records.py)")
        return replace(self, model=model)

    def hold(self, data: mujoco.MjData, configuration: str | Mapping[str, float]) -> None:
        """Hold the object in ``configuration`` (``"a"``, ``"b"`` or ``{joint: value}``).

        Only for a scene from :meth:`with_joint_holds`. Sets the joints' positions (zero
        velocities) and switches their holds on at those values, see :func:`hold_joints`.
        """
        values = (self.configuration(configuration) if isinstance(configuration, str)
                  else dict(configuration))
        self.set_joint_values(data, values, forward=False)
        held = set(self.held_joints)
        hold_joints(self.model, data, {k: v for k, v in values.items() if k in held})
        mujoco.mj_forward(self.model, data)


def _check_configuration(configuration: str) -> str:
    if configuration not in CONFIGURATIONS:
        raise ValueError(f"configuration must be one of {CONFIGURATIONS}, got {configuration!r}")
    return configuration
