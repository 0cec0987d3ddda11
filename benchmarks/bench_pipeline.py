"""Time of the main job per scene and per stage, against its floor (issue 20).

    python benchmarks/bench_pipeline.py [SCENE ...] [--views 36] [--out DIR] [--no-manipulate]
                                        [--photo-route SCENE]

For each scene (default: every bundled scene) runs ``sim.evaluate.evaluate_scene`` at the main
job's default configuration (36 views per ring, the arm's FK poses, seed 0, manipulation on),
exactly what ``python -m sim.evaluate`` runs, and prints:

- the scene's wall time and each stage's seconds (``timings_s``; the two captures run side by
  side in two processes, and so do the two configurations' SfM and dense stages);
- the floor, measured in the same run: rendering the images plus extracting their SIFT features
  with the settings the reconstruction ships, per configuration (the capture's own ``render_s``
  and the configuration stage's ``sfm_extract``), the larger of A and B, since the two run side by
  side: no run of this method goes under it, every image must be made and described once;
- the ratio of the scene's wall time to that floor (issue 20's goal: <= 2);
- the process's CPU seconds (user + system, children included), which other load on the machine
  inflates much less than the wall time.

One JSON line per scene (``BENCH {...}``), then a table. ``--photo-route SCENE`` also times the
route without poses on that scene's captures: the images alone, copied into plain folders (no
``cameras.json``: focal length unknown, SfM from the images), through ``artrecon.reconstruct``.

By default every run starts from an empty stage cache (a temporary folder), so the times are
fresh; ``--out DIR`` keeps the cache (a second run then reports the times of the cached stages as
they were built). Timings depend on the machine's load: no asserts.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

import sim  # noqa: F401
from artrecon.files import read_json
from sim import evaluate
from sim.scene import list_scenes


def _cpu_s() -> float:
    """User + system CPU seconds of this process and of its finished children."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def floor_of(result: dict) -> dict:
    """Render and SIFT-extraction seconds per configuration, as this run measured them."""
    out = {}
    model_dir = Path(result["_model_dir"])
    for c in ("a", "b"):
        capture = read_json(Path(result["_sets"][c]) / "capture.json")
        render = float(capture.get("timings", {}).get("render_s", float("nan")))
        conf = read_json(model_dir / c / "configuration.json")
        extract = float(conf.get("timings", {}).get("sfm_extract", float("nan")))
        out[c] = {"render_s": render, "extract_s": extract}
    out["floor_s"] = max(v["render_s"] + v["extract_s"] for v in (out["a"], out["b"]))
    return out


def photo_route(result: dict, work: Path) -> dict:
    """Seconds of ``artrecon.reconstruct`` on the scene's images alone (no camera file)."""
    from artrecon import reconstruct

    plain = {}
    for c in ("a", "b"):
        plain[c] = work / f"plain_{c}"
        shutil.copytree(Path(result["_sets"][c]) / "images", plain[c])
    t, cpu = time.perf_counter(), _cpu_s()
    model = reconstruct(plain["a"], plain["b"], out_dir=work / "photo_model", progress=False)
    return {"wall_s": time.perf_counter() - t, "cpu_s": _cpu_s() - cpu,
            "links": len(model.links), "joints": len(model.joints),
            "focal_px": (model.metadata.get("intrinsics") or {}).get("fx")}


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
    args = p.parse_args()
    names = args.scenes or list_scenes()
    tmp = tempfile.TemporaryDirectory(prefix="bench-pipeline-")
    out = args.out or Path(tmp.name)
    ev = evaluate.EvalConfig(views=args.views, seed=args.seed,
                             manipulate=not args.no_manipulate, progress=False)
    rows = []
    try:
        for name in names:
            t, cpu = time.perf_counter(), _cpu_s()
            r = evaluate.evaluate_scene(name, ev, out)
            wall, cpu = time.perf_counter() - t, _cpu_s() - cpu
            row = {"scene": name, "views_per_ring": args.views, "wall_s": round(wall, 1),
                   "cpu_s": round(cpu, 1), "passed": r.get("passed"),
                   "error": r.get("error"), "cached": r.get("cached_stages"),
                   "stages_s": {k: round(v, 1) for k, v in r["timings_s"].items()
                                if v is not None}}
            if not r.get("error"):
                f = floor_of(r)
                row.update(floor_s=round(f["floor_s"], 1), floor=f,
                           ratio=round(wall / f["floor_s"], 2))
                if args.photo_route == name:
                    row["photo_route"] = photo_route(r, Path(tempfile.mkdtemp(dir=out)))
            rows.append(row)
            print("BENCH " + json.dumps(row), flush=True)
    finally:
        tmp.cleanup()
    stages = [k for k in evaluate.STAGES if any(k in r["stages_s"] for r in rows)]
    print("\nscene          wall s  cpu s  floor s  wall/floor  " + "  ".join(
        f"{k[:10]:>10s}" for k in stages) + "  verdict")
    for r in rows:
        print(f"{r['scene']:14s}{r['wall_s']:7.1f}{r['cpu_s']:7.1f}"
              f"{r.get('floor_s', float('nan')):9.1f}{r.get('ratio', float('nan')):12.2f}  "
              + "  ".join(f"{r['stages_s'].get(k, float('nan')):10.1f}" for k in stages)
              + ("  PASS" if r["passed"] else f"  FAIL{' (error)' if r['error'] else ''}"))
    walls = sorted(r["wall_s"] for r in rows)
    if walls:
        print(f"\nmedian wall {walls[len(walls) // 2]:.1f} s, max {walls[-1]:.1f} s over "
              f"{len(walls)} scene(s)")
    for r in rows:
        if "photo_route" in r:
            pr = r["photo_route"]
            print(f"photo route ({r['scene']}, images alone): {pr['wall_s']:.1f} s wall, "
                  f"{pr['cpu_s']:.1f} s CPU, {pr['links']} links, {pr['joints']} joint(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
