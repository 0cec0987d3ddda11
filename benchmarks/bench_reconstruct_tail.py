"""The reconstruction after the two configurations (matching, segmentation, free space, dense
labels, joints, writing the model): CPU and wall seconds per step, from a stage cache of
``python -m sim.evaluate`` (issue 20).

Usage: python benchmarks/bench_reconstruct_tail.py SCENE [--cache runs/eval/cache] [--out DIR]
           [--compare OTHER_OUT]

Finds the scene's captures and per-configuration stages in the cache (their ``stage.json``
records), runs :func:`artrecon.reconstruct` from them (no SfM, no dense stereo: the copies are
reused), prints one JSON line (CPU seconds of this process and its threads, wall seconds, the
pipeline's own step timings, the load average) and writes ``DIR/labels.npz`` (each dense
point's link in A and B, the matches' links: seg_labels) beside ``DIR/model``. ``--compare``
checks that another run's labels, link point files and model (timings and paths aside) are the
same bit for bit: a speed change must not change the result.

CPU seconds are the figure to compare on a shared machine: wall time grows with the others' load.
"""

from __future__ import annotations

import argparse
import filecmp
import importlib
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _stage(cache: Path, prefix: str, key: str, value: str) -> Path:
    for folder in sorted(cache.glob(f"{prefix}-*")):
        record = json.loads((folder / "stage.json").read_text())
        if record.get("inputs", {}).get(key) == value:
            return folder
    sys.exit(f"no {prefix} stage with {key}={value!r} in {cache}: run python -m sim.evaluate "
             "for the scene first (its capture and configuration stages)")


def _same(out: Path, other: Path) -> dict:
    a, b = np.load(out / "labels.npz"), np.load(other / "labels.npz")
    same = {k: bool(np.array_equal(a[k], b[k])) for k in a.files}
    plys = sorted((out / "model" / "links").glob("*.ply"))
    same["link_points"] = len(plys) == len(list((other / "model" / "links").glob("*.ply"))) \
        and all(filecmp.cmp(p, other / "model" / "links" / p.name, shallow=False) for p in plys)
    models = []
    for folder in (out, other):
        m = json.loads((folder / "model" / "model.json").read_text())
        for k in ("timings", "images_a", "images_b"):
            m["metadata"].pop(k, None)
        models.append(m)
    same["model"] = models[0] == models[1]
    return same


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--cache", default="runs/eval/cache")
    ap.add_argument("--out", default=None, help="default runs/bench_tail/SCENE")
    ap.add_argument("--compare", default=None)
    args = ap.parse_args()
    cache = Path(args.cache)
    out = Path(args.out or f"runs/bench_tail/{args.scene}")
    captures = [_stage(cache, f"capture_{c}", "scene", args.scene) for c in "ab"]
    confs = [_stage(cache, f"configuration_{c}", "capture", cap.name) / "configuration"
             for c, cap in zip("ab", captures, strict=True)]
    reconstruct = importlib.import_module("artrecon.reconstruct")
    from sim.scene import load_scene

    # the scene's own settings, as the main job's reconstruct stage applies them (scissors:
    # full-resolution stereo; without them its configurations were silently redone at half)
    config = reconstruct.with_settings(reconstruct.ReconstructConfig(),
                                       load_scene(args.scene).reconstruct_settings or {})
    saved = {}
    stage = importlib.import_module("artrecon.model_stage")  # where the run looks it up
    articulate = stage.articulate

    def keep(*a, **k):  # the labels of the dense points, which the model holds only per link
        saved["art"] = articulate(*a, **k)
        return saved["art"]

    stage.articulate = keep
    load = os.getloadavg()[0]
    wall, cpu = time.perf_counter(), time.process_time()
    model = reconstruct.reconstruct(captures[0] / "set", captures[1] / "set", poses=True,
                                    out_dir=out / "model", seed=0, config=config,
                                    overwrite=True, progress=False,
                                    configurations=tuple(confs))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    art = saved["art"]
    np.savez(out / "labels.npz", labels_a=art.labels_a, labels_b=art.labels_b,
             seg_labels=art.segmentation.labels)
    steps = {k: round(v, 2) for k, v in model.metadata["timings"].items()
             if not k.startswith(("sfm_", "dense_"))}
    row = {"scene": args.scene, "cpu_s": round(cpu, 2), "wall_s": round(wall, 2),
           "load_before": round(load, 2), "load_after": round(os.getloadavg()[0], 2),
           "steps_wall_s": steps}
    if args.compare:
        row["same_as"] = {"run": args.compare, **_same(out, Path(args.compare))}
    print(json.dumps(row))
    return 0 if not args.compare or all(v for k, v in row["same_as"].items() if k != "run") \
        else 1


if __name__ == "__main__":
    sys.exit(main())
