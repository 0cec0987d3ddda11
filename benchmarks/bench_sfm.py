"""Timing of the SfM stage: views (36 vs 72), cameras from images vs known poses, matching mode.

Renders the test hinge (tests/render_fixture.py) and runs artrecon.sfm.run_sfm on configuration A.
Prints seconds per step, ratios, and the camera-centre error after a similarity alignment.

    python benchmarks/bench_sfm.py [--views 36 72] [--exhaustive]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import render_fixture as rf  # noqa: E402

from artrecon import io, sfm  # noqa: E402
from artrecon.procrustes import similarity_transform  # noqa: E402


def run(folder: Path, work: Path, mode: str, matching: str) -> dict:
    s = io.load_image_folder(folder)
    intr, poses = io.load_cameras_json(s.cameras_file)
    kw = {"intrinsics": intr}
    if mode == "poses":
        kw["poses"] = poses
    t = time.perf_counter()
    r = sfm.run_sfm(s, work, config=sfm.SfMConfig(matching=matching), progress=False, **kw)
    total = time.perf_counter() - t
    T = r.T_world_camera()
    names = sorted(T)
    src = np.array([T[n][:3, 3] for n in names])
    dst = np.array([poses[n][:3, 3] for n in names])
    S = similarity_transform(src, dst)
    err = np.linalg.norm(S.apply(src) - dst, axis=1)
    return {"total": total, **r.timings, "registered": len(names), "n": len(s.names),
            "points": r.reconstruction.num_points3D(), "err_mm": err.max() * 1e3}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--views", type=int, nargs="+", default=[36, 72])
    p.add_argument("--exhaustive", action="store_true", help="also time exhaustive matching")
    args = p.parse_args()
    root = Path(tempfile.mkdtemp(prefix="bench_sfm-"))
    rows = []
    for n in args.views:
        folder = root / f"a{n}"
        t = time.perf_counter()
        rf.render_set(folder, "a", n)
        print(f"rendered {n} views in {time.perf_counter() - t:.1f} s")
        modes = [("images", "auto"), ("poses", "auto")]
        if args.exhaustive:
            modes.append(("images", "exhaustive"))
        for mode, matching in modes:
            r = run(folder, root / f"w{n}{mode}{matching}", mode, matching)
            rows.append((n, mode, matching, r))
            print(f"{n:3d} views  {mode:6s} {matching:10s}  total {r['total']:6.1f} s  "
                  f"(extract {r['extract']:.1f}, pairs {r['pairs']:.1f}, match {r['match']:.1f}, "
                  f"map {r['map']:.1f})  registered {r['registered']}/{r['n']}  "
                  f"points {r['points']}  max centre error {r['err_mm']:.3f} mm", flush=True)
    by = {(n, m, k): r for n, m, k, r in rows}
    for n in args.views:
        a, b = by.get((n, "images", "auto")), by.get((n, "poses", "auto"))
        if a and b:
            print(f"{n} views: known poses is {a['total'] / b['total']:.2f}x faster overall, "
                  f"{a['map'] / max(b['map'], 1e-9):.1f}x on mapping")
    if len(args.views) >= 2:
        n0, n1 = args.views[0], args.views[-1]
        a, b = by.get((n0, "images", "auto")), by.get((n1, "images", "auto"))
        if a and b:
            print(f"SfM from images, {n1} vs {n0} views: {b['total'] / a['total']:.2f}x the time")
    print("(2 shared CPU cores; wall-clock numbers vary with the load of the machine)")


if __name__ == "__main__":
    main()
