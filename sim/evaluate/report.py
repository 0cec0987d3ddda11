"""The evaluation report: ``results.json`` (its schema: :mod:`sim.evaluate.record`), ``results.md``
and the terminal table.

The pictures are :mod:`sim.evaluate.pictures`, the merged report of a sweep
:mod:`sim.evaluate.sweep_report`. Every file is written whole or not at all (:mod:`artrecon.files`).
The writer takes the runner's plain results and builds the record; everything that reads
results (results.md, the terminal table, the verdict lines) reads the typed record
(:class:`~sim.evaluate.record.Results`, :class:`~sim.evaluate.record.SceneRecord`), never the
JSON: a results.json on disk is read with :func:`sim.evaluate.record.read_results`.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from artrecon.files import write_bytes_atomic, write_json_atomic
from sim.evaluate import record

log = logging.getLogger(__name__)


def _num(v):
    if v is None:
        return None
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, np.integer):
        return int(v)
    return v


def _clean(obj):
    """JSON-ready copy: numpy to Python, NaN/inf to None, tuples to lists."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    return _num(obj)


#: How results.md names the camera source of a run (sim.evaluate.config.POSE_SOURCES).
POSE_LABELS = {"fk": "the arm's forward-kinematics poses (held fixed, checked against the images)",
               "images": "SfM from the images alone"}


def jsonable_scene(result: dict) -> dict:
    """A scene's result without the in-memory parts (keys starting with ``_``), JSON-ready."""
    return _clean({k: v for k, v in result.items() if not k.startswith("_")})


def write_results(results: dict, out_dir: Path) -> dict:
    """``results.json`` and ``results.md`` in ``out_dir``, both from the typed record of
    ``results`` (:mod:`sim.evaluate.record`: SchemaError, nothing written, for a key it does not
    hold). Returns the JSON written."""
    out_dir = Path(out_dir)
    rec = record.build(_clean(results))
    data = rec.to_json()
    write_json_atomic(out_dir / "results.json", data)
    write_bytes_atomic(out_dir / "results.md", markdown(rec).encode())
    return data


def _f(v, digits: int = 2, unit: str = "") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return f"{v:.{digits}f}{unit}"
    return str(v)


def _or(value, default):
    """``value``, or ``default`` where the record holds none."""
    return default if value is None else value


def _held(rec) -> bool:
    """Whether a nested record holds anything: not None and not read from an empty object."""
    return rec is not None and rec.present != frozenset()


def tree_verdict(r: record.SceneRecord) -> str:
    """A scene's kinematic-tree cell: ``yes``/``no`` (:func:`sim.evaluate.score_joints`'s
    ``tree_correct``), then how many estimated joints were invented and how many true joints
    were static; ``-`` when the scene was not scored."""
    if r.tree_correct is None:
        return "-"
    parts = ["yes" if r.tree_correct else "NO"]
    if r.invented_joints:
        parts.append(f"{len(r.invented_joints)} invented")
    if r.static_joints:
        parts.append(f"{len(r.static_joints)} static")
    return ", ".join(parts)


def _invented(j: record.InventedJoint) -> str:
    return (f"{j.name} ({j.type}, axis "
            f"{_f(j.angle_to_table_normal_deg, 1)} deg from the table normal)")


def tree_lines(r: record.SceneRecord) -> list[str]:
    """The kinematic-tree section of a scene: verdict, pairs, invented and static joints."""
    if r.tree_correct is None:
        return []
    pairs = ", ".join(f"{t} <- {e}" for e, t in r.pairs or []) or "none"
    moving = r.n_true_moving_joints
    out = [f"- kinematic tree: {'correct' if r.tree_correct else '**wrong**'} "
           f"({r.n_estimated_joints} estimated joint(s) for {moving} moving; true <- "
           f"estimated: {pairs}"
           + (f"; links: {', '.join(f'{k} = {v}' for k, v in r.link_correspondence.items())}"
              if r.link_correspondence else "") + ")"]
    not_by_links = [j.name for j in r.joints or []
                    if j.estimated_joint is not None and not j.paired_by_links]
    if not_by_links:
        out.append("- paired by axis geometry, not by the links they join: "
                   + ", ".join(not_by_links))
    out.append("- invented joints: " + ("; ".join(_invented(j) for j in r.invented_joints)
                                        if r.invented_joints else "none"))
    out.append("- static joints (did not move; reported as static, not to be found; their link "
               "is scored with its parent): " + (", ".join(r.static_joints)
                                                 if r.static_joints else "none"))
    return out


def status(r: record.SceneRecord) -> str:
    """A scene's status cell: ``PASS``, ``FAIL (n gates)`` or ``ERROR <stage>``."""
    if r.error:
        return "ERROR " + r.error[:60]
    if r.passed is None:
        return "-"
    failed = r.failed_gates or []
    return "PASS" if r.passed else f"FAIL ({len(failed)} gate{'s' if len(failed) > 1 else ''})"


def verdict_lines(r: record.SceneRecord) -> list[str]:
    """The verdict of a scene for results.md: PASS, or FAIL with each failed gate."""
    if r.passed is None:
        return []
    if r.passed:
        return ["**PASS**: every gate met"]
    return ["**FAIL**: " + "; ".join(
        f"{g.subject}: {g.gate} {_f(g.figure, 3)} (limit {_f(g.limit, 3)})"
        for g in r.failed_gates or [])]


def manipulation_lines(man: record.ManipulationRecord | None) -> list[str]:
    """results.md lines of a scene's manipulations: one per model joint moved."""
    if not _held(man):
        return []
    if not man.runs:
        return [f"- manipulation: {man.reason or 'not run'}"]
    out = []
    for r in man.runs:
        head = f"- manipulation of {r.model_joint} (true joint {r.true_joint or '-'})"
        if r.error or r.achieved is None:
            out.append(f"{head}: {r.error or r.reason}")
            continue
        out.append(
            f"{head}: {_f(r.achieved, 2)} of {_f(r.requested, 2)} {r.unit} "
            f"({_f(100 * r.relative_error, 1)}% off); peak force {_f(r.peak_force_n, 1)} N "
            f"(limit {_f(r.force_limit_n, 1)} N; the true joint needs "
            f"{_f(r.needed_force_n, 2)} N, at the gates' tolerance "
            f"{_f(r.force_at_gate_tolerance_n, 2)} N), grasp "
            f"{'LOST' if r.grasp_lost else 'held'}"
            f"; grasp point {r.grasp_visibility}"
            f"{' (hidden from the camera)' if r.grasp_hidden else ''} on {r.grasp_body}")
    return out


def registration_lines(reg: record.RegistrationRecord | None) -> list[str]:
    """results.md lines of a scene's registration routes and their errors against the truth."""
    if not _held(reg):
        return []
    out = []
    for name, e in (reg.truth_errors or {}).items():
        out.append(f"- registration {name}: {_f(e.rotation_deg, 3)} deg, "
                   f"{_f(e.translation_mm, 2)} mm, scale {_f(e.scale_percent, 3)}% off the "
                   f"true registration")
    return out


def _joint_cells(j: record.JointRecord | None) -> list[str]:
    """A joint's cells of the summary table (``-`` for a scene without joints)."""
    if j is None:
        return ["-", "-/-", "-", "-", "-", "-", "-"]
    return [j.name, f"{_or(j.type_true, '-')}/{j.type_estimated or '-'}",
            _f(j.axis_angle_deg, 2), _f(j.axis_position_mm, 1),
            (f"{_f(j.state_error, 2)} {_or(j.state_error_unit, '')}"
             if j.state_error is not None else "-"),
            _f(j.angle_to_table_normal_deg, 1), _f((j.confidence or {}).get("score"), 2)]


def summary_rows(results: record.Results) -> list[list[str]]:
    """One row per (scene, true moving joint): the headline figures in report units."""
    rows = []
    for name, r in results.scenes.items():
        man = r.manipulation or record.ManipulationRecord()
        man_s = (f"{_f(man.achieved, 1)}/{_f(man.requested, 1)} "
                 f"{_or(man.unit, '')} {_f(man.peak_force_n, 1)} N"
                 if man.requested is not None else
                 ("failed" if man.runs else (man.reason and "n/a") or "-"))
        model = r.model or record.ModelScore()
        hidden = model.hidden or record.SurfaceScore()
        base = [name, _f(r.segmentation_accuracy, 3),
                _f(model.accuracy_median_mm, 1), _f(model.completeness, 2),
                _f(hidden.completeness, 2),
                _f(r.camera_pose_error and r.camera_pose_error.position_median_mm, 1),
                _f(r.scale_error_pct, 2), tree_verdict(r), man_s, _f(r.wall_s, 0),
                status(r)]
        for j in r.joints or [None]:
            rows.append(base[:1] + _joint_cells(j) + base[1:])
    return rows


HEADER = ["scene", "joint", "type true/est", "axis deg", "pos mm", "state err",
          "axis-normal deg", "confidence", "seg acc", "acc mm", "compl", "compl hidden", "cam mm",
          "scale %", "tree ok", "manip achieved/req, force", "wall s", "status"]


def terminal_table(results: record.Results) -> str:
    """The summary as aligned plain text."""
    table = [HEADER, *summary_rows(results)]
    widths = [max(len(r[i]) for r in table) for i in range(len(HEADER))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def markdown(results: record.Results) -> str:
    """``results.md``: the summary table, then per scene the details and pictures."""
    meta = results.meta
    out = ["# artrecon evaluation", "",
           f"{_or(meta.date, '')}, `{_or(meta.command, '')}`, seed {meta.seed}, "
           f"{meta.views_per_ring} views per ring, "
           f"cameras: {POSE_LABELS.get(meta.poses, meta.poses)}.", "",
           "Versions: " + ", ".join(f"{k} {v}" for k, v in (meta.versions or {}).items()),
           "", "| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    out += ["| " + " | ".join(c.replace("|", "/") for c in row) + " |"
            for row in summary_rows(results)]
    gates = meta.gates or {}
    if gates:
        out += ["", "Gates: " + ", ".join(f"{k} {v}" for k, v in gates.items())]
    for name, r in results.scenes.items():
        out += ["", f"## {name}", ""]
        out += verdict_lines(r) + ([""] if r.passed is not None else [])
        if r.error:
            out += [f"**Error** in stage `{r.error_stage}`: {r.error}", ""]
        reg = r.registration
        if _held(reg):
            routes = reg.routes or {}
            cc, pnp = routes.get("camera_centres") or {}, routes.get("pnp") or {}
            agree = (reg.agreement or {}).get("comparison") or {}
            out += [f"- registration ({reg.chosen_route}): scale "
                    f"{_f(reg.scale_m_per_unit, 6)} m/unit; camera centres "
                    f"{cc.get('inliers')}/{cc.get('cameras')} cameras, rms "
                    f"{_f(cc.get('rms_mm'), 2)} mm; PnP of the fresh view "
                    + ", ".join(f"{im['inliers']}/{im['matches']} inliers, "
                                f"{_f(im['reprojection_rms_px'], 2)} px"
                                for im in pnp.get("images") or [])
                    + f" (scale from {pnp.get('scale_from')}); routes "
                    f"{_f(agree.get('translation_mm'), 2)} mm, "
                    f"{_f(agree.get('rotation_deg'), 3)} deg apart"]
        cam = r.camera_pose_error
        if _held(cam):
            out += [f"- camera poses: position median {_f(cam.position_median_mm, 2)} mm,"
                    f" max {_f(cam.position_max_mm, 2)} mm; rotation median "
                    f"{_f(cam.rotation_median_deg, 3)} deg, max "
                    f"{_f(cam.rotation_max_deg, 3)} deg ({cam.n} images)"]
        surveys = [(c, getattr(r, f"capture_{c}", None)) for c in ("a", "b")]
        surveys = [(c, s) for c, s in surveys if s is not None
                   and s.survey_centre_error_mm is not None]
        if surveys:
            out += ["- survey (the object's sphere the rings looked at, from the arm's "
                    "photographs): " + "; ".join(
                        f"{c.upper()} centre {_f(s.survey_centre_error_mm, 1)} mm off, "
                        f"radius x{_f(s.survey_radius_ratio, 3)}" for c, s in surveys)]
        model = r.model
        if _held(model):
            h = model.hidden or record.SurfaceScore()
            out += [f"- model: accuracy median {_f(model.accuracy_median_mm, 2)} mm "
                    f"(p90 {_f(model.accuracy_p90_mm, 2)}), completeness "
                    f"{_f(model.completeness, 3)}; side hidden from the final view "
                    f"({_f(model.hidden_share_of_surface, 2)} of the surface): accuracy "
                    f"{_f(h.accuracy_median_mm, 2)} mm, completeness "
                    f"{_f(h.completeness, 3)}"]
        seg = r.segmentation
        if _held(seg):
            acc_in = seg.accuracy_in or {}
            scored = seg.scored_in or {}
            out += [f"- segmentation: {_f(r.segmentation_accuracy, 3)} against the "
                    f"rendered link labels (points seen in A: {_f(acc_in.get('a'), 3)} of "
                    f"{scored.get('a', '-')}, in B: {_f(acc_in.get('b'), 3)} of "
                    f"{scored.get('b', '-')}; {_f(seg.off_surface_share, 3)} of the "
                    f"points left out: no view, or most views, put them off the object); nearest "
                    f"true surface at A: "
                    f"{_f(seg.accuracy_nearest_surface_at_a, 3)}"]
        out += tree_lines(r)
        out += manipulation_lines(r.manipulation)
        out += registration_lines(r.registration)
        ts = r.timings_s or {}
        if ts:
            out += ["- time (s): " + ", ".join(f"{k} {_f(v, 1)}" for k, v in ts.items())
                    + (f" (from cache: {', '.join(r.cached_stages)})"
                       if r.cached_stages else "")]
        for pic in (f"{name}_reconstruction.png", f"{name}_errors.png"):
            out += ["", f"![{pic}]({pic})"]
    return "\n".join(out) + "\n"
