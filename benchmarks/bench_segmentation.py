"""Segmentation speed and accuracy: artrecon.segment vs the method's fixed 1000-hypothesis loop.

Usage: python benchmarks/bench_segmentation.py [--sizes 1000 10000 100000] [--repeats 3]

Data: a synthetic 3-link chain (revolute + prismatic, tests/synthetic.py), Gaussian noise, 40%
outlier matches, a random similarity between the configurations. Both methods get the same inlier
distance and minimum link size. The baseline is the method as published (ICRA paper, III-C): 1000
random triplets per round, one Procrustes each, the transform with most inliers wins (ties by mean
squared error), its inliers become a link with that triplet transform, repeat until a round finds
fewer than the minimum link size. Accuracy: fraction of all matches labelled right (outliers must
be -1; links matched to the truth by majority) and the worst link-rotation error.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from synthetic import make_object, match_links  # noqa: E402

from artrecon.procrustes import rotation_angle, similarity_transform  # noqa: E402
from artrecon.segment import SegmentationConfig, segment_links  # noqa: E402
from artrecon.tolerances import scene_size  # noqa: E402


def paper_segmentation(pa, pb, thr, min_size, seed, iterations=1000):
    """Plain re-implementation of the published loop (the baseline; not library code)."""
    rng = np.random.default_rng(seed)
    labels = np.full(len(pa), -1)
    transforms = []
    remaining = np.arange(len(pa))
    while len(remaining) >= min_size:
        a, b = pa[remaining], pb[remaining]
        best, best_count, best_mse = None, -1, math.inf
        for _ in range(iterations):
            tri = rng.choice(len(remaining), 3, replace=False)
            try:
                t = similarity_transform(a[tri], b[tri])
            except Exception:  # collinear triplet
                continue
            r2 = np.sum((t.apply(a) - b) ** 2, axis=1)
            inl = r2 < thr * thr
            count = int(inl.sum())
            mse = float(r2[inl].mean()) if count else math.inf
            if count > best_count or (count == best_count and mse < best_mse):
                best, best_count, best_mse = t, count, mse
        if best is None or best_count < min_size:
            break
        inl = np.sum((best.apply(a) - b) ** 2, axis=1) < thr * thr
        labels[remaining[inl]] = len(transforms)
        transforms.append(best)
        remaining = remaining[~inl]
    return labels, transforms


def accuracy(labels, transforms, obj):
    mapping = match_links(labels, obj.labels, len(obj.link_motions))
    pred = np.array([mapping.get(k, -2) if k >= 0 else -1 for k in labels])
    label_acc = float(np.mean(pred == obj.labels))
    rot_err = max(
        (
            np.degrees(rotation_angle(t.rotation.T @ obj.link_motions[mapping[k]].rotation))
            for k, t in enumerate(transforms)
            if k in mapping
        ),
        default=float("nan"),
    )
    found = len(set(mapping.values()))
    return label_acc, rot_err, found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--noise", type=float, default=0.003, help="point noise sigma (world)")
    parser.add_argument("--outliers", type=float, default=0.4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3, help="artrecon timing: best of N")
    args = parser.parse_args()
    warm = make_object(99, "pair", ("revolute",), 100, 0.0, 0.2)  # imports, BLAS threads
    segment_links(warm.points_a, warm.points_b)
    cfg = SegmentationConfig()
    print(f"3-link chain, noise sigma {args.noise}, {args.outliers:.0%} outliers, seed {args.seed}")
    header = (
        f"{'matches':>8} | {'artrecon s':>10} {'label acc':>9} {'rot err':>8} {'links':>5}"
        f" {'hyps':>6} | {'paper s':>8} {'label acc':>9} {'rot err':>8} {'links':>5} | speed-up"
    )
    print(header)
    print("-" * len(header))
    for n in args.sizes:
        n_in = int(round(n * (1 - args.outliers)))
        per_link = n_in // 4  # root has 2 shares, each child 1
        obj = make_object(args.seed, "chain", ("revolute", "prismatic"), per_link, args.noise,
                          args.outliers)
        size_a = scene_size(obj.points_a[obj.labels >= 0])
        inlier = max(cfg.inlier_threshold, 6 * args.noise / size_a)
        cfg_n = SegmentationConfig(inlier_threshold=inlier)
        t_ours = math.inf
        for _ in range(max(1, args.repeats)):
            t0 = time.perf_counter()
            seg = segment_links(obj.points_a, obj.points_b, cfg_n, seed=args.seed)
            t_ours = min(t_ours, time.perf_counter() - t0)
        ours = accuracy(seg.labels, seg.transforms, obj)

        thr = inlier * scene_size(obj.points_b)
        min_size = max(cfg.min_link_points, math.ceil(cfg.min_link_fraction * len(obj.points_a)))
        t0 = time.perf_counter()
        labels_p, transforms_p = paper_segmentation(obj.points_a, obj.points_b, thr, min_size,
                                                    args.seed)
        t_paper = time.perf_counter() - t0
        paper = accuracy(labels_p, transforms_p, obj)
        print(
            f"{len(obj.points_a):>8} | {t_ours:>10.3f} {ours[0]:>9.4f} {ours[1]:>7.3f}d"
            f" {ours[2]:>5} {sum(seg.hypotheses):>6} | {t_paper:>8.3f} {paper[0]:>9.4f}"
            f" {paper[1]:>7.3f}d {paper[2]:>5} | {t_paper / t_ours:>6.1f}x"
        )


if __name__ == "__main__":
    main()
