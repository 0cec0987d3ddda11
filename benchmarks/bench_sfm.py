"""Timing of the SfM stage: views (36 vs 72), cameras from images vs known poses, matching mode,
and the known-pose path at its previous settings against its defaults.

Renders the test hinge (tests/render_fixture.py) and runs artrecon.sfm.run_sfm on configuration A,
or runs on capture folders given with ``--capture`` (e.g. a ``capture_a-*/set`` of a
``python -m sim.evaluate`` cache). Prints wall and CPU seconds per step (extract, pairs, match,
map, check), ratios, and the camera-centre error after a similarity alignment.

    python benchmarks/bench_sfm.py [--views 36 72] [--exhaustive]
    python benchmarks/bench_sfm.py --capture runs/eval/cache/capture_a-*/set --poses-only

"Known poses, previous" is the known-pose path with the settings before issue 20's changes
(8 pose neighbours, 5 rounds of bundle adjustment, COLMAP's 100 RANSAC trials at least); the
database is written directly in both (that change has no switch).

Measured at e2d5e1c on the pliers capture A (121 images, 640x480, known poses; 2 cores shared,
load ~8; CPU seconds): previous settings 51.1 (extract 21.9, match 22.1, map 6.5, check 0.5; 13831
points), defaults 36.4 (extract 17.9, match 12.4, map 5.5, check 0.5; 14128 points). main before
this branch, extraction through COLMAP's 32-px pass and a Python keypoint loop: extract 25.0,
match 22.3, map 7.8, check 0.5 (55.5).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from artrecon import io, sfm  # noqa: E402
from artrecon.procrustes import similarity_transform  # noqa: E402

PREVIOUS = {"pose_neighbours": 8, "pose_ba_refinements": 5, "pose_verify_min_trials": 100}
STEPS = ("extract", "pairs", "match", "map", "pose_check")


def run(folder: Path, work: Path, mode: str, matching: str, **settings) -> dict:
    s = io.load_image_folder(folder)
    intr, poses = io.load_cameras_json(s.cameras_file)
    kw = {"intrinsics": intr}
    if mode.startswith("poses"):
        kw["poses"] = poses
    t, c = time.perf_counter(), time.process_time()
    r = sfm.run_sfm(s, work, config=sfm.SfMConfig(matching=matching, **settings),
                    progress=False, **kw)
    total, total_cpu = time.perf_counter() - t, time.process_time() - c
    T = r.T_world_camera()
    names = sorted(T)
    src = np.array([T[n][:3, 3] for n in names])
    dst = np.array([poses[n][:3, 3] for n in names])
    S = similarity_transform(src, dst)
    err = np.linalg.norm(S.apply(src) - dst, axis=1)
    return {"total": total, "total_cpu": total_cpu, **r.timings, "registered": len(names),
            "n": len(s.names), "points": r.reconstruction.num_points3D(),
            "err_mm": err.max() * 1e3}


def line(label: str, r: dict) -> str:
    steps = ", ".join(f"{k.replace('pose_check', 'check')} {r[k]:.1f}/{r[k + '_cpu']:.1f}"
                      for k in STEPS if k in r)
    return (f"{label:38s} total {r['total']:6.1f} s wall, {r['total_cpu']:6.1f} s CPU  "
            f"(wall/CPU s: {steps})  registered {r['registered']}/{r['n']}  "
            f"points {r['points']}  max centre error {r['err_mm']:.3f} mm")


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--views", type=int, nargs="+", default=[36, 72])
    p.add_argument("--exhaustive", action="store_true", help="also time exhaustive matching")
    p.add_argument("--capture", type=Path, nargs="+", default=[],
                   help="capture folders (images/ + cameras.json) instead of rendering")
    p.add_argument("--poses-only", action="store_true",
                   help="only the known-pose path (previous settings and defaults)")
    args = p.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_sfm-"))
    folders = []
    if args.capture:
        folders = [(str(f), f) for f in args.capture]
    else:
        import render_fixture as rf

        for n in args.views:
            folder = root / f"a{n}"
            t = time.perf_counter()
            rf.render_set(folder, "a", n)
            print(f"rendered {n} views in {time.perf_counter() - t:.1f} s")
            folders.append((f"{n} views", folder))
    by = {}
    for k, (label, folder) in enumerate(folders):
        modes = [("poses, previous", "auto", PREVIOUS), ("poses", "auto", {})]
        if not args.poses_only:
            modes.insert(0, ("images", "auto", {}))
            if args.exhaustive:
                modes.append(("images", "exhaustive", {}))
        for mode, matching, settings in modes:
            r = run(folder, root / f"w{k}{mode}{matching}".replace(", ", "_"), mode, matching,
                    **settings)
            by[(label, mode, matching)] = r
            print(line(f"{label} {mode} {matching}", r), flush=True)
        a, b = by.get((label, "images", "auto")), by.get((label, "poses", "auto"))
        if a and b:
            print(f"{label}: known poses is {a['total_cpu'] / b['total_cpu']:.2f}x cheaper "
                  f"(CPU) overall, {a['map_cpu'] / max(b['map_cpu'], 1e-9):.1f}x on mapping")
        a, b = by.get((label, "poses, previous", "auto")), by.get((label, "poses", "auto"))
        if a and b:
            ratios = ", ".join(f"{k} {a[k + '_cpu'] / max(b[k + '_cpu'], 1e-9):.2f}x"
                               for k in STEPS if k in a and k != "pairs")
            print(f"{label}: known poses, defaults vs previous settings: "
                  f"{a['total_cpu'] / b['total_cpu']:.2f}x less CPU ({ratios})")
    if not args.capture and len(args.views) >= 2:
        n0, n1 = f"{args.views[0]} views", f"{args.views[-1]} views"
        a, b = by.get((n0, "images", "auto")), by.get((n1, "images", "auto"))
        if a and b:
            print(f"SfM from images, {n1} vs {n0}: {b['total'] / a['total']:.2f}x the time")
    print("(2 shared CPU cores; wall-clock numbers vary with the load of the machine, CPU "
          "seconds less so)")


if __name__ == "__main__":
    main()
