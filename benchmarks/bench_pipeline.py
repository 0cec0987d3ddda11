"""Time of the whole method per scene, per stage, as the number of views grows.

    python benchmarks/bench_pipeline.py [SCENE ...] [--views 18 36 72] [--out DIR] [--no-manipulate]

For each scene and each number of views *per full capture ring* (the capture has three full rings
at 20/40/60 deg and a shorter top ring, so 18/36/72 per ring are about 61/121/242 images per
configuration), runs ``sim.evaluate.evaluate_scene`` (capture both configurations, SfM, dense,
matching, segmentation and joints, registration, manipulation, scoring) and prints the seconds of
each stage, each stage's share of the whole, and the ratio of the whole run to SIFT extraction
alone on the same two image sets (COLMAP's extractor with the reconstruction's settings: the
floor no run of this method goes under, since every image must be read and described once).

Stage results are cached in ``--out`` (default ``runs/bench``); the times printed for a cached
stage are those measured when it was built, so a re-run prints the same table quickly. Delete the
folder for fresh timings. Timings depend on the machine's load: no asserts.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import sim  # noqa: F401
from sim import evaluate


def sift_only(set_dir: Path) -> float:
    """Seconds of COLMAP SIFT extraction alone on one image set (the reconstruction's settings)."""
    from artrecon.io import load_cameras_json, load_image_folder
    from artrecon.sfm import SfMConfig, extract

    iset = load_image_folder(set_dir)
    intr = load_cameras_json(iset.cameras_file)[0] if iset.cameras_file else None
    with tempfile.TemporaryDirectory(prefix="bench-sift-") as tmp:
        t = time.perf_counter()
        extract(iset, Path(tmp) / "database.db", intr, SfMConfig())
        return time.perf_counter() - t


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenes", nargs="*", default=["pliers"])
    p.add_argument("--views", type=int, nargs="+", default=[18, 36, 72],
                   help="views per full capture ring (default 18 36 72)")
    p.add_argument("--out", type=Path, default=Path("runs/bench"))
    p.add_argument("--no-manipulate", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    rows = []
    for name in args.scenes:
        for n in args.views:
            ev = evaluate.EvalConfig(views=n, seed=args.seed, manipulate=not args.no_manipulate,
                                     progress=False)
            t = time.perf_counter()
            r = evaluate.evaluate_scene(name, ev, args.out / f"views{n}")
            wall = time.perf_counter() - t
            if r["error"]:
                print(f"{name} @ {n} views/ring: FAILED {r['error']}", file=sys.stderr)
            ts = {k: v for k, v in r["timings_s"].items() if v is not None}
            total = sum(ts.values())
            n_img = sum((r.get(f"capture_{c}") or {}).get("n_captured", 0) for c in "ab")
            sift = (sum(sift_only(Path(d)) for d in r["_sets"].values()) if "_sets" in r
                    else None)
            rows.append((name, n, n_img, ts, total, wall, sift, r["cached_stages"]))
            print(f"\n{name}: {n} views per ring, {n_img} images in all; stage sum {total:.1f} s"
                  f" (this run's wall time {wall:.1f} s"
                  f"{', cached: ' + ', '.join(r['cached_stages']) if r['cached_stages'] else ''})")
            for k in evaluate.STAGES:
                if k in ts:
                    print(f"  {k:22s} {ts[k]:8.1f} s  {100 * ts[k] / total:5.1f} %")
            if sift:
                print(f"  SIFT extraction alone (both sets): {sift:.1f} s; whole run / SIFT = "
                      f"{total / sift:.1f}; reconstruction (sfm..assign) / SIFT = "
                      f"{sum(ts.get(k, 0) for k in evaluate.STAGES[2:7]) / sift:.1f}")
    print("\nscene   views/ring  images  total s  " + "  ".join(f"{k[:10]:>10s}"
                                                             for k in evaluate.STAGES)
          + "  whole/SIFT")
    for name, n, n_img, ts, total, _, sift, _ in rows:
        print(f"{name:8s}{n:10d}  {n_img:6d}  {total:7.1f}  "
              + "  ".join(f"{ts.get(k, float('nan')):10.1f}" for k in evaluate.STAGES)
              + (f"  {total / sift:10.1f}" if sift else "         n/a"))
    for name in args.scenes:
        mine = [r for r in rows if r[0] == name]
        for (_, n0, _, _, t0, *_), (_, n1, _, _, t1, *_) in zip(mine, mine[1:], strict=False):
            print(f"{name}: {n0} -> {n1} views per ring: total x{t1 / t0:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
