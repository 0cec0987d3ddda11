"""The accuracy gates: one table, one verdict, used by the main job and by the tests alike.

``python -m sim.evaluate`` marks every scene PASS or FAIL with :func:`verdict` and exits non-zero
when one fails; tests/test_gates.py runs that same default configuration and asserts the same
verdict, gate by gate. Never loosen a limit to pass: a scene that misses one is a finding, and it
stays visible as a FAIL row with its figure and the limit.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

#: The limits (issue 19). Angles in degrees, lengths in millimetres, shares in [0, 1].
GATES = {
    # every moving joint, estimated from the model and paired with the true one by its links
    "axis_angle_deg": 0.5,
    "axis_position_mm": 2.0,  # revolute joints: distance between the estimated and true axes
    "state_error_deg": 0.5,
    "state_error_mm": 1.0,
    # the model's points against the rendered link labels (sim.evaluate.scoring)
    "segmentation_accuracy": 0.97,
    "off_object_share": 0.05,
    # the arm's motion along the estimated joint, measured along the true joint
    "manipulation_relative_error": 0.05,
    # the weld's peak force: at most this factor times the force the true joint needs (the same
    # grasp and motion along the true joint) or the force of a joint as wrong as the gates above
    # allow (axis turned 0.5 deg and moved 2 mm: the grasp is stiff, so an accepted axis must
    # not fail for force), and never held to less than the floor (N): a joint that needs almost
    # nothing still gets the force of a 200 g weight
    "manipulation_force_factor": 3.0,
    "manipulation_force_floor_n": 2.0,
    # registration by the paper's route (PnP of a fresh image + hand-eye), against the truth
    "registration_pnp_rotation_deg": 0.5,
    "registration_pnp_translation_mm": 3.0,
    "registration_pnp_scale_percent": 1.0,
}


#: Every gate a scene's verdict checks, by name (a check's ``gate``; ``state_error`` stands for
#: ``state_error_deg`` and ``state_error_mm``, ``manipulation`` for a motion that did not happen
#: and ``manipulation_relative_error``): the tests gate each of them on every bundled scene.
GATE_NAMES = ("error", "joint_found", "type", "axis_angle_deg", "axis_position_mm",
              "state_error", "tree", "invented_joints", "segmentation_accuracy",
              "off_object_share", "manipulation", "registration_pnp")


def family(gate: str) -> str:
    """The :data:`GATE_NAMES` entry a check's gate belongs to."""
    if gate.startswith("state_error"):
        return "state_error"
    if gate.startswith("manipulation"):
        return "manipulation"
    if gate.startswith("registration_pnp"):
        return "registration_pnp"
    return gate


@dataclass(frozen=True)
class GateCheck:
    """One gate applied to one figure of a scene."""

    gate: str
    """name: a key of :data:`GATES`, or a structural gate (``error``, ``type``, ``joint_found``,
    ``tree``, ``invented_joints``, ``manipulation``)"""
    subject: str
    """what it was applied to: a joint's name, ``segmentation``, ``model``, ``manipulation`` or
    the stage that failed"""
    figure: float | str | None
    """the measured figure (None: not measured)"""
    limit: float | str | None
    """the limit it must meet"""
    passed: bool

    def to_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        fig = f"{self.figure:.3g}" if isinstance(self.figure, float) else str(self.figure)
        lim = f"{self.limit:g}" if isinstance(self.limit, float) else str(self.limit)
        return f"{self.subject}: {self.gate} {fig} (limit {lim})"


def _at_most(gate: str, subject: str, figure, limit: float) -> GateCheck:
    ok = figure is not None and float(figure) <= limit
    return GateCheck(gate, subject, None if figure is None else float(figure), limit, ok)


def _at_least(gate: str, subject: str, figure, limit: float) -> GateCheck:
    ok = figure is not None and float(figure) >= limit
    return GateCheck(gate, subject, None if figure is None else float(figure), limit, ok)


def joint_checks(row: dict) -> list[GateCheck]:
    """The gates of one true moving joint's row (:func:`sim.evaluate.scoring.score_joints`)."""
    name = row["name"]
    if row.get("estimated_joint") is None:
        return [GateCheck("joint_found", name, "missed", "estimated", False)]
    out = [GateCheck("type", name, row.get("type_estimated"), row["type_true"],
                     bool(row.get("type_correct")))]
    out.append(_at_most("axis_angle_deg", name, row.get("axis_angle_deg"),
                        GATES["axis_angle_deg"]))
    if row["type_true"] == "revolute":
        out.append(_at_most("axis_position_mm", name, row.get("axis_position_mm"),
                            GATES["axis_position_mm"]))
    unit = row.get("state_error_unit", "deg")
    out.append(_at_most(f"state_error_{unit}", name, row.get("state_error"),
                        GATES[f"state_error_{unit}"]))
    return out


def joint_passes(row: dict) -> bool:
    """Whether one joint row meets every joint gate."""
    return all(c.passed for c in joint_checks(row))


def checks(result: dict, manipulate: bool = True) -> list[GateCheck]:
    """Every gate of one scene's result (``sim.evaluate`` results.json scene entry).

    Parameters
    ----------
    result : dict
        A scene's result as :func:`sim.evaluate.runner.evaluate_scene` returns it.
    manipulate : bool
        Whether the run manipulated (``--no-manipulate`` leaves the manipulation ungated).
    """
    if result.get("error"):
        return [GateCheck("error", result.get("error_stage") or "scene", result["error"],
                          "no error", False)]
    out: list[GateCheck] = []
    rows = result.get("joints") or []
    for row in rows:
        out += joint_checks(row)
    swapped = [r["name"] for r in rows if r.get("links_swapped")]
    tree_ok = bool(result.get("tree_correct")) and not swapped
    out.append(GateCheck("tree", "kinematic tree",
                         "exact" if tree_ok else ("parent and child swapped at " +
                                                  ", ".join(swapped) if swapped else "wrong"),
                         "exact (each link's parent)", tree_ok))
    invented = [j["name"] for j in result.get("invented_joints") or []]
    out.append(GateCheck("invented_joints", "kinematic tree", ", ".join(invented) or "none",
                         "none", not invented))
    out.append(_at_least("segmentation_accuracy", "segmentation",
                         result.get("segmentation_accuracy"), GATES["segmentation_accuracy"]))
    seg = result.get("segmentation") or {}
    out.append(_at_most("off_object_share", "segmentation", seg.get("off_surface_share"),
                        GATES["off_object_share"]))
    reg = (result.get("registration") or {}).get("truth_errors", {}).get("pnp")
    if reg is None:
        out.append(GateCheck("registration_pnp", "registration", "no PnP route", "ran", False))
    else:
        for key, gate in (("rotation_deg", "registration_pnp_rotation_deg"),
                          ("translation_mm", "registration_pnp_translation_mm"),
                          ("scale_percent", "registration_pnp_scale_percent")):
            out.append(_at_most(gate, "registration (PnP route)", reg.get(key), GATES[gate]))
    if manipulate:
        out += manipulation_checks(result.get("manipulation") or {})
    return out


def manipulation_checks(man: dict) -> list[GateCheck]:
    """The gates of each manipulation run (every joint of the model moved in turn): no error,
    the grasp held, the motion within ``manipulation_relative_error`` of the request along the
    true joint, the peak force under the run's limit."""
    runs = man.get("runs") or []
    if not runs:
        return [GateCheck("manipulation", "manipulation", man.get("reason") or "not run",
                          "a motion", False)]
    out = []
    for r in runs:
        subject = f"manipulation of {r['model_joint']}"
        if r.get("error") or r.get("achieved") is None:
            out.append(GateCheck("manipulation", subject,
                                 r.get("error") or r.get("reason") or "no motion", "a motion",
                                 False))
            continue
        out.append(GateCheck("manipulation_grasp_held", subject,
                             "lost" if r["grasp_lost"] else "held", "held", not r["grasp_lost"]))
        out.append(_at_most("manipulation_relative_error", subject, r["relative_error"],
                            GATES["manipulation_relative_error"]))
        out.append(_at_most("manipulation_peak_force_n", subject, r["peak_force_n"],
                            r["force_limit_n"]))
    return out


def verdict(result: dict, manipulate: bool = True) -> dict:
    """``{"passed": bool, "failed": [GateCheck.to_dict(), ...]}`` of one scene."""
    failed = [c for c in checks(result, manipulate) if not c.passed]
    return {"passed": not failed, "failed": [c.to_dict() for c in failed]}
