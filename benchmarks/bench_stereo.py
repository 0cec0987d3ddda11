"""The dense stage's stereo against the rendered depth: which pairs see the object, and how far
their disparities are from the truth (issue 23: the dense surfaces the links' motions lean on).

Usage: python benchmarks/bench_stereo.py RUNS [scene ...] [--pairs N]

RUNS is the ``--out`` folder of ``benchmarks/bench_gates.py`` (or of a sweep of the main job):
its ``cache/`` holds each run's reconstruction, whose configurations' SfM models and images are
read, and each capture's ground truth (the rendered depth and link labels). Nothing is
reconstructed: every stereo pair of a configuration as the dense stage forms it
(:func:`artrecon.dense.stereo_plan`; ``--pairs N``: N of them, evenly spread) is matched again by
the stage's own :func:`artrecon.dense.pair_disparity`, and the disparity of each of the object's
pixels (any link's label) in the first rectified image is compared with the true one, from the
rendered depth through the pair's rectification. Per run and configuration it prints

- ``held``: the pairs whose search range holds at least 90% of the object's true disparities
  (a pair that misses the object gives the surface nothing of it);
- ``valid`` / ``kept``: the share of the object's pixels with a disparity, and of those the stage
  keeps as points (not dropped beside a depth edge);
- ``median`` and ``MAD``: the disparity error (px, signed: negative is farther than the truth)
  over the valid pixels within 2 px of the truth, and ``off``: the share beyond 2 px
  (occlusions and mismatches); ``pair medians``: the range of the pairs' own medians;
- ``whole px``: the share of valid disparities within 1/8 px of a whole pixel (0.31 by chance;
  SGBM's sub-pixel steps cling to whole pixels).

The runs must be the main job's (camera poses from the arm's forward kinematics: the SfM
models are in the robot's frame and their relative poses are the true ones). The truth is read
for scoring only.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from artrecon import dense
from artrecon.configuration import load_configuration
from artrecon.settings import ReconstructConfig, with_settings
from sim.evaluate.scoring import truth_views
from sim.scene import load_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_link_motions import reconstructions  # noqa: E402  (the same runs' folders)

#: Errors beyond this many pixels count as off the surface (occlusion, mismatch), not noise.
OFF_PX = 2.0


def object_truth(pair: dense.PairDisparity, K: np.ndarray, depth: np.ndarray,
                 labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows, columns (in the first rectified image) and true disparities of the object's pixels
    of the reference view (``K``, ``depth`` and ``labels`` at full resolution), one per
    rectified pixel."""
    h, w = pair.disparity.shape
    vv, uu = np.nonzero(np.isfinite(depth) & (depth > 0) & (labels > 0))
    z = depth[vv, uu]
    X = np.column_stack([(uu - K[0, 2]) * z / K[0, 0], (vv - K[1, 2]) * z / K[1, 1], z])
    X = X @ pair.R1.T
    left = X @ pair.P1[:, :3].T
    right = X @ pair.P2[:, :3].T + pair.P2[:, 3]
    u, v = left[:, 0] / left[:, 2], left[:, 1] / left[:, 2]
    d = u - right[:, 0] / right[:, 2]
    col, row = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    on = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    _, first = np.unique(row[on] * w + col[on], return_index=True)
    return row[on][first], col[on][first], d[on][first]


def configuration_figures(folder: Path, config: dense.DenseConfig, pairs: int) -> dict:
    """The figures of one configuration (module docstring)."""
    sfm = load_configuration(folder).sfm
    plan = dense.stereo_plan(sfm, config)
    set_dir = Path(sfm.image_dir).parent
    names = [im["file"] for im in
             json.loads((set_dir / "ground_truth" / "poses.json").read_text())["images"]]
    truth = dict(zip(names, truth_views(set_dir), strict=True))
    chosen = plan.pairs
    if 0 < pairs < len(chosen):
        chosen = [chosen[k] for k in np.linspace(0, len(chosen) - 1, pairs).round().astype(int)]
    held, valid, kept, errors, medians, whole = 0, [], [], [], [], []
    for i, j in chosen:
        pair = dense.pair_disparity(plan.views[i], plan.views[j], plan.image(i), plan.image(j),
                                    plan.shared_points(i, j), config)
        if pair is None:
            continue
        K, _, depth, labels = truth[plan.views[i].name]
        row, col, d_true = object_truth(pair, K, depth, labels)
        if len(d_true) == 0:
            continue
        lo, num = pair.search
        held += np.mean((d_true > lo) & (d_true < lo + num - 1)) >= 0.9
        ok = pair.valid[row, col]
        valid.append(ok.mean())
        kept.append(pair.kept[row, col][ok].mean() if ok.any() else 0.0)
        err = pair.disparity[row, col][ok] - d_true[ok]
        errors.append(err)
        near = np.abs(err) <= OFF_PX
        if near.sum() >= 50:
            medians.append(float(np.median(err[near])))
        frac = pair.disparity[row, col][ok] % 1.0
        whole.append(np.minimum(frac, 1.0 - frac) <= 1 / 8)
    err = np.concatenate(errors) if errors else np.zeros(0)
    near = err[np.abs(err) <= OFF_PX]
    median = float(np.median(near)) if len(near) else float("nan")
    return {"pairs": len(chosen), "held": int(held),
            "valid": float(np.mean(valid)) if valid else float("nan"),
            "kept": float(np.mean(kept)) if kept else float("nan"),
            "median_px": median,
            "mad_px": float(np.median(np.abs(near - median))) if len(near) else float("nan"),
            "off": float(np.mean(np.abs(err) > OFF_PX)) if len(err) else float("nan"),
            "pair_medians_px": [min(medians), max(medians)] if medians else None,
            "whole_px": float(np.mean(np.concatenate(whole))) if whole else float("nan")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, help="a bench_gates.py --out folder")
    parser.add_argument("scenes", nargs="*", help="only these scenes (default: every run)")
    parser.add_argument("--pairs", type=int, default=0,
                        help="pairs per configuration, evenly spread (0: every pair)")
    args = parser.parse_args(argv)
    runs_dir = args.runs / "runs"
    if not runs_dir.is_dir():
        print(f"{args.runs}: no runs/ folder; give the --out folder of benchmarks/bench_gates.py",
              file=sys.stderr)
        return 2
    found = reconstructions(args.runs)
    print(f"{'run':26s} cfg {'held':>7s} {'valid':>6s} {'kept':>5s} {'median':>7s} {'MAD':>5s} "
          f"{'off':>5s} {'pair medians':>15s} {'whole px':>8s}")
    for run in sorted(runs_dir.iterdir()):
        if not (run / "results.json").is_file():
            continue
        result = next(iter(json.loads((run / "results.json").read_text())["scenes"].values()))
        if args.scenes and result["scene"] not in args.scenes:
            continue
        if run.name not in found:
            print(f"{run.name}: no cached reconstruction in {args.runs / 'cache'}; left out",
                  file=sys.stderr)
            continue
        scene = load_scene(result["scene"])
        config = with_settings(ReconstructConfig(), dict(scene.reconstruct_settings)).dense
        for which in "ab":
            f = configuration_figures(found[run.name] / which, config, args.pairs)
            spread = ("{:+.2f}..{:+.2f}".format(*f["pair_medians_px"])
                      if f["pair_medians_px"] else "-")
            print(f"{run.name:26s}  {which}  {f['held']:3d}/{f['pairs']:<3d} {f['valid']:6.2f} "
                  f"{f['kept']:5.2f} {f['median_px']:+7.3f} {f['mad_px']:5.3f} {f['off']:5.2f} "
                  f"{spread:>15s} {f['whole_px']:8.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
