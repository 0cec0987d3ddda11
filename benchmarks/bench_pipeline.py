"""Time of the main job per scene and per stage, against its floor (issue 20).

    python benchmarks/bench_pipeline.py [SCENE ...] [--views 36] [--out DIR] [--no-manipulate]
                                        [--photo-route SCENE] [--set capture.FIELD=VALUE ...]

For each scene (default: every bundled scene) runs ``sim.evaluate.evaluate_scene`` at the main
job's default configuration (36 views per ring, the arm's FK poses, seed 0, manipulation on),
exactly what ``python -m sim.evaluate`` runs, and prints:

- the scene's wall time and each stage's seconds (``timings_s``; the two configurations' chains
  -- capture, SfM, dense -- run side by side in two processes, so ``sfm`` and ``dense``, the sums
  of A's and B's, are more than they add to the wall time, and the manipulation runs beside the
  scoring); ``chains``: the longer of the two chains (capture + per-configuration stage, as
  built), ``model``: the model stage (matching A x B to the joints and dense labels), ``tail``:
  the fresh view to the end (registration, scoring, manipulation);
- where the CPU went in each configuration (``cpu``): the capture's view plan (IK), arm motion,
  rendering and PNG writing, SfM's SIFT extraction, matching and triangulation, dense stereo,
  as the stages measured them (CPU seconds are much less inflated by other load than wall
  seconds);
- the floor, measured in the same run: rendering the images plus extracting their SIFT features
  with the settings the reconstruction ships, per configuration (the capture's own ``render_s``
  and the configuration stage's ``sfm_extract``), the larger of A and B, since the two run side by
  side: no run of this method goes under it, every image must be made and described once;
  ``floor_cpu_s`` the same in CPU seconds;
- the ratio of the scene's wall time to that floor (issue 20's goal: <= 2);
- the process's CPU seconds (user + system, children included), which other load on the machine
  inflates much less than the wall time.

One JSON line per scene (``BENCH {...}``), then a table. Each line and the accuracy table also
hold what the run's scoring measured against the truth (``accuracy``: per joint the axis
direction's error in degrees, the axis position's in mm, the state's in degrees or mm; the
segmentation accuracy), so that a lever that changes the results shows its cost beside its time.
``--photo-route SCENE`` also times the route without poses on that scene's captures: the images
alone, copied into plain folders (no ``cameras.json``: focal length unknown, SfM from the
images), through ``artrecon.reconstruct``, and scores its joints the same way, the model brought
into the world by its configuration A cameras' centres against the true ones (a similarity:
the route's scale is unknown).

By default every run starts from an empty stage cache (a temporary folder), so the times are
fresh; ``--out DIR`` keeps the cache (a second run then reports the times of the cached stages as
they were built). Timings depend on the machine's load: no asserts.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import sim  # noqa: F401
from artrecon.errors import InputError
from artrecon.files import read_json
from artrecon.settings import parse_settings
from sim import evaluate
from sim.capture_config import SET_EXAMPLE, capture_settings
from sim.scene import list_scenes

NAN = float("nan")
#: Stages after the model (timings_s), one after the other but for the last two: the
#: manipulation beside the scoring.
TAIL = ("fresh_view", "registration", "scoring", "manipulation")


def _cpu_s() -> float:
    """User + system CPU seconds of this process and of its finished children."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def floor_of(result: dict) -> dict:
    """Per configuration, as this run measured them: the capture's CPU seconds per step (from its
    cache record: the capture writes no timings beside the images), the per-configuration
    stage's (SfM steps, dense), and the floor (render + SIFT extraction, wall and CPU)."""
    out = {}
    model_dir = Path(result["_model_dir"])
    for c in ("a", "b"):
        capture = read_json(Path(result["_sets"][c]).parent / "stage.json")
        ct = capture.get("timings", {})
        conf = read_json(model_dir / c / "configuration.json")
        t = conf.get("timings", {})
        out[c] = {"render_s": ct.get("render_s", NAN), "extract_s": t.get("sfm_extract", NAN),
                  "chain_s": capture.get("build_s", NAN) + t.get("sfm", NAN) + t.get("dense", NAN),
                  "cpu": {"plan": ct.get("plan_cpu_s", NAN), "move": ct.get("move_cpu_s", NAN),
                          "render": ct.get("render_cpu_s", NAN), "png": ct.get("png_cpu_s", NAN),
                          "extract": t.get("sfm_extract_cpu", NAN),
                          "match": t.get("sfm_match_cpu", NAN), "map": t.get("sfm_map_cpu", NAN),
                          "dense": t.get("dense_cpu", NAN)}}
    out["floor_s"] = max(v["render_s"] + v["extract_s"] for v in (out["a"], out["b"]))
    out["floor_cpu_s"] = max(v["cpu"]["render"] + v["cpu"]["extract"]
                             for v in (out["a"], out["b"]))
    return out


def summary(result: dict, wall: float, parallel: bool = True) -> dict:
    """A scene's floor, ratio, its time by part (chains, model, tail) and the CPU seconds per step
    of each configuration (:func:`floor_of`); ``parallel``: the run had its second process
    (``EvalConfig.parallel_capture``)."""
    f = floor_of(result)
    st, rt = result["timings_s"], result.get("reconstruct_timings_s", {})
    return {"floor_s": round(f["floor_s"], 1), "floor_cpu_s": round(f["floor_cpu_s"], 1),
            "ratio": round(wall / f["floor_s"], 2),
            "chains_s": round(max(f["a"]["chain_s"], f["b"]["chain_s"]), 1),
            "model_s": round(rt.get("total", NAN), 1),
            # the manipulation's span holds the scoring when the two run side by side
            "tail_s": round(sum(st.get(k) or 0.0 for k in TAIL[:2])
                            + (max if parallel else sum)(st.get(k) or 0.0 for k in TAIL[2:]), 1),
            "cpu_by_configuration": {c: {k: round(v, 1) for k, v in f[c]["cpu"].items()}
                                     for c in ("a", "b")}}


def joint_errors(rows: list[dict]) -> list[dict]:
    """The scoring's joint rows (``sim.evaluate.scoring.score_joints``) cut to the figures the
    gates read: the true joint, the estimated type, the axis direction's error (deg), the axis
    position's (mm, revolute) and the state's (deg or mm); None where the scoring had none."""

    def rounded(x, digits):
        return None if x is None else round(float(x), digits)

    return [{"joint": j["name"], "type": j.get("type_estimated"),
             "axis_deg": rounded(j.get("axis_angle_deg"), 4),
             "position_mm": rounded(j.get("axis_position_mm"), 4),
             "state_error": rounded(j.get("state_error"), 4),
             "state_unit": j.get("state_error_unit")} for j in rows]


def accuracy_of(result: dict) -> dict:
    """What the scene's scoring measured against the truth: its joints (:func:`joint_errors`)
    and the segmentation accuracy."""
    seg = result.get("segmentation_accuracy")
    return {"joints": joint_errors(result.get("joints") or []),
            "segmentation": None if seg is None else round(float(seg), 4)}


def photo_route(result: dict, work: Path) -> dict:
    """Seconds of ``artrecon.reconstruct`` on the scene's images alone (no camera file), and its
    joints' errors against the truth (``score_joints``), the model brought into the world by the
    similarity of its A cameras' centres onto the true ones
    (:func:`sim.evaluate.scoring.true_registration`; the route has no robot to register it by)."""
    from artrecon import reconstruct
    from artrecon.register.apply import apply_registration
    from sim.evaluate.scoring import score_joints, true_registration
    from sim.scene import load_scene

    plain = {}
    for c in ("a", "b"):
        plain[c] = work / f"plain_{c}"
        shutil.copytree(Path(result["_sets"][c]) / "images", plain[c])
    t, cpu = time.perf_counter(), _cpu_s()
    model = reconstruct(plain["a"], plain["b"], out_dir=work / "photo_model", progress=False)
    wall, cpu = time.perf_counter() - t, _cpu_s() - cpu
    S = true_registration(work / "photo_model", Path(result["_sets"]["a"]))
    scores = score_joints(load_scene(result["scene_file"]), apply_registration(model, S))
    return {"wall_s": wall, "cpu_s": cpu, "links": len(model.links), "joints": len(model.joints),
            "focal_px": [round(float(c["focal_px"]), 2)
                         for c in (model.metadata.get("intrinsics") or {}).values()
                         if c.get("focal_px") is not None],
            "accuracy": joint_errors(scores["joints"]),
            "invented_joints": len(scores["invented_joints"])}


def print_tables(rows: list[dict]) -> None:
    """The wall-time table (the scene, its floor, its parts and stages) and the CPU table (each
    configuration's steps)."""
    stages = [k for k in evaluate.STAGES if any(k in r["stages_s"] for r in rows)]
    parts = ("floor_s", "floor_cpu_s", "ratio", "chains_s", "model_s", "tail_s")
    print("\nscene          wall s  cpu s" + "".join(f"{k[:-2] if k.endswith('_s') else k:>10s}"
                                                 for k in parts)
          + "".join(f"{k[:11]:>12s}" for k in stages) + "  verdict")
    for r in rows:
        print(f"{r['scene']:14s}{r['wall_s']:7.1f}{r['cpu_s']:7.1f}"
              + "".join(f"{r.get(k, NAN):10.2f}" if k == "ratio" else f"{r.get(k, NAN):10.1f}"
                        for k in parts)
              + "".join(f"{r['stages_s'].get(k, NAN):12.1f}" for k in stages)
              + ("  PASS" if r["passed"] else f"  FAIL{' (error)' if r['error'] else ''}"))
    print("\nscene          joint                 type        axis deg   pos mm  state err  "
          "seg acc")
    for r in rows:
        acc = r.get("accuracy") or {}
        for j in acc.get("joints") or [{"joint": "-"}]:
            print(f"{r['scene']:14s} {_text(j.get('joint'), 21)} {_text(j.get('type'), 10)}"
                  f"{_num(j.get('axis_deg'), 3, 10)}{_num(j.get('position_mm'), 3, 9)}"
                  f"{_num(j.get('state_error'), 3, 8)} {_text(j.get('state_unit'), 3)}"
                  f"{_num(acc.get('segmentation'), 3, 8)}")
    steps = ("plan", "move", "render", "png", "extract", "match", "map", "dense")
    print("\nCPU seconds per configuration" + " " * 6 + "".join(f"{k:>9s}" for k in steps))
    for r in rows:
        for c, cpu in (r.get("cpu_by_configuration") or {}).items():
            print(f"{r['scene']:14s} {c.upper()}" + " " * 19
                  + "".join(f"{cpu.get(k, NAN):9.1f}" for k in steps))


def _text(x, width: int) -> str:
    return f"{'-' if x is None else str(x)[:width]:{width}s}"


def _num(x, digits: int, width: int) -> str:
    return f"{'-':>{width}s}" if x is None else f"{x:{width}.{digits}f}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenes", nargs="*", default=None, help="default: every bundled scene")
    p.add_argument("--views", type=int, default=evaluate.EvalConfig().views,
                   help="views per full capture ring (default: the main job's)")
    p.add_argument("--out", type=Path, default=None,
                   help="keep the stage cache here (default: a fresh temporary folder)")
    p.add_argument("--no-manipulate", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--photo-route", metavar="SCENE",
                   help="also time the route without poses on this scene's images")
    p.add_argument("--set", dest="settings", action="append", default=[],
                   metavar="capture.FIELD=VALUE|views.FIELD=VALUE",
                   help="time a capture setting instead of the main job's, as python -m "
                        "sim.evaluate --set takes it (e.g. views.fill=0.9)")
    args = p.parse_args()
    try:
        settings = capture_settings(parse_settings(args.settings, SET_EXAMPLE))
    except InputError as e:
        p.error(str(e))
    names = args.scenes or list_scenes()
    tmp = tempfile.TemporaryDirectory(prefix="bench-pipeline-")
    out = args.out or Path(tmp.name)
    ev = evaluate.EvalConfig(views=args.views, seed=args.seed,
                             manipulate=not args.no_manipulate, progress=False,
                             capture_settings=settings)
    rows = []
    try:
        for name in names:
            t, cpu = time.perf_counter(), _cpu_s()
            r = evaluate.evaluate_scene(name, ev, out)
            # this process's CPU and its finished children's, and the kept second process's
            wall = time.perf_counter() - t
            cpu = _cpu_s() - cpu + (r.get("second_process_cpu_s") or 0.0)
            row = {"scene": name, "views_per_ring": args.views, "settings": args.settings,
                   "wall_s": round(wall, 1),
                   "cpu_s": round(cpu, 1), "passed": r.get("passed"),
                   "failed_gates": r.get("failed_gates"), "error": r.get("error"),
                   "cached": r.get("cached_stages"),
                   "stages_s": {k: round(v, 1) for k, v in r["timings_s"].items()
                                if v is not None}}
            row["accuracy"] = accuracy_of(r)
            if not r.get("error"):
                row.update(summary(r, wall, ev.parallel_capture))
                if args.photo_route == name:
                    row["photo_route"] = photo_route(r, Path(tempfile.mkdtemp(dir=out)))
            rows.append(row)
            print("BENCH " + json.dumps(row), flush=True)
    finally:
        tmp.cleanup()
    print_tables(rows)
    walls = [r["wall_s"] for r in rows]
    if walls:
        print(f"\nmedian wall {statistics.median(walls):.1f} s, max {max(walls):.1f} s over "
              f"{len(walls)} scene(s)" + (f" with {', '.join(args.settings)}" if args.settings
                                          else ""))
    for r in rows:
        if "photo_route" in r:
            pr = r["photo_route"]
            errors = "; ".join(
                f"{j['joint']}: axis {_num(j['axis_deg'], 3, 0)} deg, position "
                f"{_num(j['position_mm'], 3, 0)} mm, state {_num(j['state_error'], 3, 0)} "
                f"{j['state_unit']}" for j in pr["accuracy"])
            print(f"photo route ({r['scene']}, images alone): {pr['wall_s']:.1f} s wall, "
                  f"{pr['cpu_s']:.1f} s CPU, {pr['links']} links, {pr['joints']} joint(s) "
                  f"({errors}; {pr['invented_joints']} invented), focal {pr['focal_px']} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
