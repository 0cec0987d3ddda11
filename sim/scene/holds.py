"""Joint holds: keep the object still while the arm works around it.

A hold is a MuJoCo joint equality ``q = const`` per object joint, added to the scene's spec before
compiling (:func:`add_joint_holds`, :meth:`sim.scene.Scene.with_joint_holds`), inactive until
switched on at the values to hold (:func:`hold_joints`) and off again (:func:`release_joints`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import mujoco

#: Name prefix of the joint holds (:func:`add_joint_holds`): ``"hold:" + joint name``.
HOLD_PREFIX = "hold:"
#: Stiffness of a hold (MuJoCo ``solref``: time constant, damping ratio). The time constant is
#: MuJoCo's smallest stable one at the stage's 2 ms timestep (twice the step); with
#: HOLD_SOLIMP the loaded hinges of the bundled objects (truck bed, scraper boom) settle within
#: 1e-5 rad of the held value and stay there for minutes (their friction loss, MuJoCo's soft
#: constraint on velocity only, lets them creep by 1-3 mrad in 3 s).
HOLD_SOLREF = (0.004, 1.0)
#: Impedance of a hold (MuJoCo ``solimp``): near-rigid at any violation.
HOLD_SOLIMP = (0.99, 0.999, 0.001, 0.5, 2.0)


def add_joint_holds(spec: mujoco.MjSpec, joints: Iterable[str]) -> list[str]:
    """Add to ``spec`` one inactive hold per joint: a MuJoCo joint equality ``q = const``.

    A hold is a physical constraint, as stiff as MuJoCo allows (:data:`HOLD_SOLREF`,
    :data:`HOLD_SOLIMP`): switched on (:func:`hold_joints`) it keeps a joint where it was put
    against gravity for as long as the simulation runs, where the joints' friction loss lets a
    loaded joint creep. It is not a weld of the object to the world: contacts still act, so a
    collision of the arm with the object still shows as contacts (a hold only keeps the joint
    from giving way to it). Holds start inactive; the model behaves as without them until one is
    switched on.

    Parameters
    ----------
    spec : mujoco.MjSpec
        The scene's spec (e.g. ``mujoco.MjSpec.from_file(scene.path)``), before compiling.
    joints : iterable of str
        Joint names (hinges or slides) of the spec.

    Returns
    -------
    names : list of str
        Names of the added equality constraints, ``HOLD_PREFIX + joint``.
    """
    out = []
    for joint in joints:
        name = HOLD_PREFIX + joint
        spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                          name=name, name1=joint, name2="", active=False,
                          data=[0.0] * 12, solref=list(HOLD_SOLREF), solimp=list(HOLD_SOLIMP))
        out.append(name)
    return out


def _hold_id(model: mujoco.MjModel, joint: str) -> int:
    e = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, HOLD_PREFIX + joint)
    if e < 0:
        raise KeyError(f"the model has no hold on joint {joint!r}; compile it with "
                       f"Scene.with_joint_holds() or add_joint_holds(spec, [...])")
    return e


def hold_joints(model: mujoco.MjModel, data: mujoco.MjData, values: Mapping[str, float]) -> None:
    """Switch on the holds of joints ``{name: value}`` at those values (rad or m).

    Writes each hold's target into ``model.eq_data`` (so the model should be the caller's own,
    e.g. from :meth:`Scene.with_joint_holds`) and sets ``data.eq_active``. Does not move the
    joints: put them at the values first (:meth:`Scene.set_joint_values`), or the hold pulls them
    there.

    Raises
    ------
    KeyError
        A joint has no hold in ``model``.
    """
    for joint, value in values.items():
        e = _hold_id(model, joint)
        j = int(model.eq_obj1id[e])
        # MuJoCo's joint equality is q - qpos0 = c0 + c1 (q2 - q2_0) + ...; one joint: c0 only
        model.eq_data[e, :5] = [float(value) - float(model.qpos0[model.jnt_qposadr[j]]),
                                0.0, 0.0, 0.0, 0.0]
        data.eq_active[e] = 1


def release_joints(model: mujoco.MjModel, data: mujoco.MjData,
                   joints: Iterable[str] | None = None) -> None:
    """Switch off the holds of ``joints`` (default: every hold of the model)."""
    if joints is None:
        ids = [e for e in range(model.neq)
               if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_EQUALITY, e) or ""
                   ).startswith(HOLD_PREFIX)]
    else:
        ids = [_hold_id(model, j) for j in joints]
    for e in ids:
        data.eq_active[e] = 0
