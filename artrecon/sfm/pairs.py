"""Which images to match, and their matching and geometric verification (COLMAP).

With camera poses each image is matched with those whose optical axes are nearest its own
(:func:`pose_pairs`); without, a window in file-name order plus retrieval neighbours
(:func:`select_pairs`). :func:`match` writes ``OUT/pairs.txt`` and the verified matches into
the database.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap

from artrecon.sfm.config import SfMConfig


def pose_pairs(names: list[str], poses: dict[str, np.ndarray], config: SfMConfig
               ) -> list[tuple[str, str]]:
    """Image pairs from camera poses: each image with the ``config.pose_neighbours`` images
    whose optical axes are nearest to its own, within ``config.pose_max_angle_deg``.

    Parameters
    ----------
    names : list of str
        Images with a pose (in matching order).
    poses : dict of str to (4, 4) float
        ``T_world_camera`` per image (OpenCV: the optical axis is the third column).

    Returns
    -------
    list of (str, str)
        Each unordered pair once, in name order.
    """
    if len(names) < 2:
        return []
    axes = np.array([poses[n][:3, 2] for n in names], dtype=float)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    np.fill_diagonal(cos, -np.inf)
    min_cos = np.cos(np.deg2rad(config.pose_max_angle_deg))
    pairs = set()
    k = min(config.pose_neighbours, len(names) - 1)
    for i in range(len(names)):
        for j in np.argsort(-cos[i], kind="stable")[:k]:
            if cos[i, j] >= min_cos:
                pairs.add((min(i, int(j)), max(i, int(j))))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def select_pairs(names: list[str], features: dict, config: SfMConfig, seed: int = 0,
                 poses: dict[str, np.ndarray] | None = None) -> list[tuple[str, str]]:
    """Image pairs to match: from the poses when given (:func:`pose_pairs`), else a window in
    name order plus retrieval neighbours (see :mod:`artrecon.sfm`)."""
    n = len(names)
    if config.matching == "auto" and poses is not None:
        posed = [name for name in names if name in poses]
        return pose_pairs(posed, poses, config)
    if config.matching == "exhaustive":
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    pairs = set()
    for i in range(n):
        for d in range(1, config.sequential_window + 1):
            if i + d < n:
                pairs.add((i, i + d))
    if config.matching == "auto":
        rng = np.random.default_rng(seed)
        samples = []
        for name in names:
            desc = features[name][2].astype(np.float32)
            if len(desc) > config.retrieval_sample:
                desc = desc[rng.choice(len(desc), config.retrieval_sample, replace=False)]
            desc /= np.linalg.norm(desc, axis=1, keepdims=True) + 1e-9
            samples.append(desc)
        score = np.zeros((n, n))
        for i in range(n):
            for j in range(i + 1, n):
                if len(samples[i]) == 0 or len(samples[j]) == 0:
                    continue
                sim = samples[i] @ samples[j].T
                a = sim.argmax(1)
                b = sim.argmax(0)
                mutual = b[a] == np.arange(len(a))
                good = mutual & (sim[np.arange(len(a)), a] > 0.85)
                score[i, j] = score[j, i] = good.sum()
        for i in range(n):
            for j in np.argsort(-score[i])[: config.retrieval_neighbours]:
                if j != i and score[i, j] > 0:
                    pairs.add((min(i, j), max(i, j)))
    elif config.matching != "sequential":
        raise ValueError(f"SfMConfig.matching: expected 'auto', 'exhaustive' or 'sequential', "
                         f"got {config.matching!r}")
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def match(database_path: Path, pairs: list[tuple[str, str]], out_dir: Path,
          config: SfMConfig, posed: bool = False) -> None:
    """Match SIFT features of the listed pairs and verify them geometrically (``posed``: the
    images have camera poses, so their pairs overlap well; see ``pose_verify_min_trials``)."""
    pairs_file = out_dir / "pairs.txt"
    pairs_file.write_text("".join(f"{a} {b}\n" for a, b in pairs))
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = config.num_threads
    popt = pycolmap.ImportedPairingOptions()
    popt.match_list_path = str(pairs_file)
    vopt = pycolmap.TwoViewGeometryOptions()
    if posed:
        vopt.ransac.min_num_trials = config.pose_verify_min_trials
    pycolmap.match_image_pairs(database_path, matching_options=mopt, pairing_options=popt,
                               verification_options=vopt, device=pycolmap.Device.cpu)
