"""The merged report of a sweep (:mod:`sim.evaluate.sweep`): every run, per scene and setting
the median, worst and spread over seeds, and its pictures (:mod:`sim.evaluate.pictures`).

Everything here reads the typed record (:mod:`sim.evaluate.record`: :class:`~sim.evaluate.
record.Results` of the sweep layout, its :class:`~sim.evaluate.record.RunRecord`), never the
JSON; a results.json on disk is read with :func:`sim.evaluate.record.read_results`."""

from __future__ import annotations

import logging
from pathlib import Path

from artrecon.files import write_bytes_atomic, write_json_atomic
from sim.evaluate import record
from sim.evaluate.pictures import (
    _median,
    _write_png,
    draw_strength_chart,
    draw_sweep_errors,
    run_bars,
)
from sim.evaluate.report import POSE_LABELS, _clean, _f

log = logging.getLogger(__name__)

# The merged report of a sweep (sim.evaluate.sweep): every run, per scene and setting the median,
# worst and spread over seeds, and two kinds of pictures: the gated errors of every run per scene
# and seed (sweep_errors.png), and of a robustness sweep the errors against each perturbation's
# strength (sweep_<perturbation>.png).

def sweep_summary(runs: list[record.RunRecord]) -> list[record.GroupSummary]:
    """Per group of runs (same scene and setting, seeds apart): seeds, how many passed, and for
    every gated figure the median, worst (largest: every figure is an error, the segmentation
    as ``1 - accuracy``) and spread (max - min) over the runs that measured it.

    Parameters
    ----------
    runs : list of RunRecord
        The sweep's runs (``results.json`` ``runs``).
    """
    groups: dict[str, list[record.RunRecord]] = {}
    for rec in runs:
        groups.setdefault(rec.group, []).append(rec)
    out = []
    for name, recs in groups.items():
        spec = recs[0].spec
        figures: dict[str, dict] = {}
        for rec in recs:
            manip = rec.spec.config.get("manipulate", True)
            for label, value, gate, unit in run_bars(rec.result, manip):
                f = figures.setdefault(label, {"unit": unit, "gate": gate, "values": {}})
                f["values"][str(rec.spec.config["seed"])] = value
        for f in figures.values():
            vals = [v for v in f["values"].values() if v is not None]
            f.update(n=len(vals), missing=len(recs) - len(vals),
                     median=_median(vals) if vals else None, worst=max(vals) if vals else None,
                     spread=(max(vals) - min(vals)) if vals else None)
            f["worst_passes"] = f["worst"] is not None and f["worst"] <= f["gate"]
        out.append(record.GroupSummary.from_json(_clean({
            "group": name, "scene": spec.scene, "perturbation": spec.perturbation,
            "strength": spec.strength, "label": spec.label,
            "seeds": [r.spec.config["seed"] for r in recs], "runs": len(recs),
            "passed": sum(r.status == "passed" for r in recs),
            "failed": [r.id for r in recs if r.status != "passed"], "figures": figures})))
    return out


def run_reason(rec: record.RunRecord) -> str:
    """Why a run did not pass: its error, or the gates it failed (empty if it passed)."""
    res = rec.result
    if rec.status == "not run":
        return "not run"
    if res is not None and res.error:
        return res.error
    return "; ".join(f"{g.subject}: {g.gate}" for g in (res and res.failed_gates) or [])


def run_name(rec: record.RunRecord) -> str:
    """``scene seed k [label]`` of a run."""
    spec = rec.spec
    return (f"{(rec.result and rec.result.scene) or spec.scene} seed {spec.config['seed']}"
            + (f" {spec.label}" if spec.label else ""))


SWEEP_HEADER = ["run", "status", "attempts", "axis deg", "pos mm", "state", "seg acc",
                "off obj", "wall s", "error or failed gates"]


def sweep_rows(results: record.Results) -> list[list[str]]:
    """One row per run: its worst joint figures and status."""
    rows = []
    for rec in results.runs:
        r = rec.result
        js = (r and r.joints) or []

        def worst(key, js=js):
            vals = [getattr(j, key) for j in js if getattr(j, key) is not None]
            return max(vals) if vals else None

        units = sorted({j.state_error_unit for j in js if j.state_error_unit})
        state = worst("state_error")
        seg = r and r.segmentation
        rows.append([rec.id, rec.status.upper() if rec.status != "passed" else "PASS",
                     str(rec.attempts if rec.attempts is not None else 0),
                     _f(worst("axis_angle_deg"), 3), _f(worst("axis_position_mm"), 2),
                     "-" if state is None else f"{state:.3f} {'/'.join(units)}",
                     _f(r and r.segmentation_accuracy, 3),
                     _f(seg and seg.off_surface_share, 3),
                     _f(r and r.wall_s, 0), run_reason(rec)[:70]])
    return rows


def sweep_table(results: record.Results) -> str:
    """The sweep as aligned plain text: every run, then per group passed / runs."""
    table = [SWEEP_HEADER, *sweep_rows(results)]
    widths = [max(len(r[i]) for r in table) for i in range(len(SWEEP_HEADER))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in table]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines += ["", "per scene over seeds: " + ", ".join(
        f"{g.group} {g.passed}/{g.runs} passed" for g in results.summary)]
    return "\n".join(lines)


def sweep_markdown(results: record.Results) -> str:
    """``results.md`` of a sweep: verdict, per scene over seeds, every run, pictures."""
    meta = results.meta
    sw = meta.sweep or record.SweepMeta()
    runs = results.runs
    passed = sum(r.status == "passed" for r in runs)
    out = ["# artrecon sweep", "",
           f"{_or(meta.date, '')}, `{_or(meta.command, '')}`: {len(runs)} runs, seeds "
           f"{meta.seeds}, backend {sw.backend}"
           + (f" at {sw.address}" if sw.address else "")
           + (f", {sw.jobs} jobs" if sw.jobs else "")
           + (f", {sw.wall_s:.0f} s wall" if sw.wall_s is not None else "")
           + f"; {meta.views_per_ring} views per ring, cameras: "
           f"{POSE_LABELS.get(meta.poses, meta.poses)}"
           + ("" if _or(meta.manipulate, True) else ", no manipulation") + ".", "",
           "Versions: " + ", ".join(f"{k} {v}" for k, v in (meta.versions or {}).items()),
           "", f"**{passed} of {len(runs)} runs passed every gate.**"
           + ("" if passed == len(runs) else " Failed: " + "; ".join(
               f"{run_name(r)} ({run_reason(r)[:120]})" for r in runs
               if r.status != "passed")), "",
           "## Per scene over seeds", "",
           "Every gated figure as an error (the segmentation as 1 - accuracy): median, worst and "
           "spread (max - min) over the runs that measured it; *missing*: runs without the "
           "figure (an error or a dead worker).", "",
           "| scene / setting | seeds | passed | figure | median | worst | spread | gate | "
           "missing |", "|---|---|---|---|---|---|---|---|---|"]
    for g in results.summary:
        first = True
        for label, f in g.figures.items():
            cells = ([g.group, ", ".join(str(s) for s in g.seeds),
                      f"{g.passed}/{g.runs}"] if first else ["", "", ""])
            first = False
            worst = _f(f.worst, 3) + ("" if f.worst_passes else " **FAIL**")
            out.append("| " + " | ".join(cells + [
                label, f"{_f(f.median, 3)} {f.unit}".strip(), worst,
                _f(f.spread, 3), f"{f.gate:g}", str(f.missing)]) + " |")
        if first:
            out.append(f"| {g.group} | {', '.join(str(s) for s in g.seeds)} | "
                       f"{g.passed}/{g.runs} | - | - | - | - | - | {g.runs} |")
    out += ["", "![errors per scene and seed](sweep_errors.png)", ""]
    for name in (meta.perturbations or {}):
        out += [f"![{name}](sweep_{name}.png)", ""]
    out += ["## Every run", "", "| " + " | ".join(SWEEP_HEADER + ["worker", "report"]) + " |",
            "|" + "---|" * (len(SWEEP_HEADER) + 2)]
    for rec, row in zip(runs, sweep_rows(results), strict=True):
        w = rec.worker or {}
        row[-1] = run_reason(rec)[:200]
        where = f"{w.get('host')} pid {w.get('pid')}" if w.get("host") else "-"
        link = f"[{rec.dir}]({rec.dir}/results.md)" if rec.result is not None else "-"
        out.append("| " + " | ".join(c.replace("|", "/") for c in row + [where, link]) + " |")
    return "\n".join(out) + "\n"


def _or(value, default):
    """``value``, or ``default`` where the record holds none."""
    return default if value is None else value


def write_sweep(results: record.Results, out_dir: Path) -> dict:
    """A sweep's merged ``results.json``, ``results.md`` and pictures in ``out_dir``, all from
    the record ``results``. Returns the JSON written."""
    out_dir = Path(out_dir)
    data = results.to_json()
    write_json_atomic(out_dir / "results.json", data)
    try:
        _write_png(out_dir / "sweep_errors.png", draw_sweep_errors(results))
        for name, axis in (results.meta.perturbations or {}).items():
            _write_png(out_dir / f"sweep_{name}.png", draw_strength_chart(results, name, axis))
    except Exception as err:  # pictures must not sink the numbers
        log.warning("sweep pictures failed: %s", err)
    write_bytes_atomic(out_dir / "results.md", sweep_markdown(results).encode())
    return data
