"""Matches across the two configurations, lifted to 3D-3D pairs.

The SIFT keypoints and descriptors of both SfM runs are reused from their COLMAP databases; only
keypoints that belong to a 3D point of their model take part. Each image of configuration A is
compared with the few images of B that look most alike (most mutual nearest neighbours among a
sample of descriptors, which picks views from a similar direction without a common frame). In each
such image pair, descriptors are matched by mutual nearest neighbours with Lowe's ratio test. Every
surviving match votes for the pair (3D point of A, 3D point of B); pairs are then made one-to-one
by keeping, for each 3D point, its most voted partner.

No epipolar verification is done between an A and a B image: the object moved between them, so a
single two-view geometry would reject the moving link; the rigid-link RANSAC downstream
(:mod:`artrecon.segment`) removes the outliers instead.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pycolmap

from artrecon.errors import ReconstructionError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MatchConfig:
    """Settings of the cross-configuration matching."""

    ratio: float = 0.8
    """Lowe's ratio: best distance below this x second best (SIFT paper: 0.8)."""
    images_per_image: int = 4
    """B images compared with each A image (the most similar ones); matching time grows with it
    and 4 neighbours already give every 3D point several votes on a ring of views."""
    retrieval_sample: int = 200
    """Descriptors per image used to rank image similarity (200: the ranking is stable and the
    n_a x n_b sampled comparisons stay a few seconds)."""
    min_votes: int = 1
    """A 3D-3D pair needs at least this many image pairs agreeing on it."""
    min_matches: int = 12
    """Fewer 3D-3D pairs than this is a failure (segmentation needs several per link)."""


@dataclass
class CrossMatches:
    """3D-3D correspondences between the two configurations.

    Attributes
    ----------
    points_a, points_b : (n, 3) float
        Matched 3D points in the SfM frames of A and B.
    point3D_ids_a, point3D_ids_b : (n,) int
        Their ids in the two reconstructions.
    votes : (n,) int
        Image pairs that support each match.
    colours : (n, 3) uint8
        Colour of the A point.
    """

    points_a: np.ndarray
    points_b: np.ndarray
    point3D_ids_a: np.ndarray
    point3D_ids_b: np.ndarray
    votes: np.ndarray
    colours: np.ndarray

    def __len__(self) -> int:
        return len(self.points_a)

    def subset(self, mask: np.ndarray) -> CrossMatches:
        """The matches selected by a boolean or index array."""
        return CrossMatches(self.points_a[mask], self.points_b[mask], self.point3D_ids_a[mask],
                            self.point3D_ids_b[mask], self.votes[mask], self.colours[mask])


def _tracked_features(sfm, allowed: set | None = None
                      ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per registered image: (point3D ids (k,), unit float descriptors (k, 128)) of the keypoints
    that belong to a 3D point (in ``allowed``, if given)."""
    rec = sfm.reconstruction
    out = {}
    with pycolmap.Database.open(sfm.database_path) as db:
        for img in rec.images.values():
            if not img.has_pose:
                continue
            idx = [k for k, p in enumerate(img.points2D) if p.has_point3D()
                   and (allowed is None or p.point3D_id in allowed)]
            if not idx:
                continue
            desc = db.read_descriptors(img.image_id)
            desc = np.asarray(desc.data if hasattr(desc, "data") else desc)
            pids = np.array([img.points2D[k].point3D_id for k in idx], dtype=np.int64)
            d = desc[idx].astype(np.float32)
            d /= np.linalg.norm(d, axis=1, keepdims=True) + 1e-9
            out[img.name] = (pids, d)
    return out


def _top2(sim: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: index of the largest similarity, its distance and the second best distance."""
    rows = np.arange(len(sim))
    nn = sim.argmax(axis=1)
    best = sim[rows, nn]
    sim[rows, nn] = -np.inf
    second = sim.max(axis=1)
    sim[rows, nn] = best
    to_dist = lambda x: np.sqrt(np.clip(2.0 - 2.0 * x, 0.0, None))  # noqa: E731 unit vectors
    return nn, to_dist(best), to_dist(second)


def _mutual_ratio(da: np.ndarray, db: np.ndarray, ratio: float,
                  sim: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of mutual nearest neighbours that pass the ratio test both ways.

    ``sim`` is ``da @ db.T`` when the caller already has it; the B -> A direction uses its
    transpose (one product per pair, not two).
    """
    if len(da) < 2 or len(db) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    if sim is None:
        sim = da @ db.T
    a_nn, a_d1, a_d2 = _top2(sim)
    b_nn, b_d1, b_d2 = _top2(sim.T)
    ia = np.arange(len(da))
    ok = (b_nn[a_nn] == ia) & (a_d1 < ratio * a_d2) & (b_d1[a_nn] < ratio * b_d2[a_nn])
    return ia[ok], a_nn[ok]


def _similar_images(fa: dict, fb: dict, k: int, sample: int, seed: int) -> dict[str, list[str]]:
    rng = np.random.default_rng(seed)

    def pick(d):
        return d if len(d) <= sample else d[rng.choice(len(d), sample, replace=False)]

    names_a, names_b = sorted(fa), sorted(fb)
    sa = [pick(fa[n][1]) for n in names_a]
    sb = [pick(fb[n][1]) for n in names_b]
    # One product per image of A against every sampled descriptor of B (many tiny products
    # are dominated by BLAS call overhead), then the mutual ratio test per block.
    bounds = np.cumsum([0] + [len(d) for d in sb])
    all_b = np.concatenate(sb) if sb else np.zeros((0, 128), np.float32)
    out = {}
    for i, name in enumerate(names_a):
        sim = sa[i] @ all_b.T
        scores = np.array([len(_mutual_ratio(sa[i], sb[j], 0.9,
                                             sim[:, bounds[j]:bounds[j + 1]])[0])
                           for j in range(len(sb))])
        out[name] = [names_b[j] for j in np.argsort(-scores)[:k] if scores[j] > 0]
    return out


def match_configurations(sfm_a, sfm_b, config: MatchConfig = MatchConfig(), seed: int = 0,
                         allowed_a: set | None = None, allowed_b: set | None = None
                         ) -> CrossMatches:
    """3D-3D matches between two SfM models of the object in configurations A and B.

    Parameters
    ----------
    sfm_a, sfm_b : artrecon.sfm.SfMResult
    config : MatchConfig
    seed : int
    allowed_a, allowed_b : set of int, optional
        Only these 3D point ids take part (e.g. the points on the object, not the background).

    Returns
    -------
    CrossMatches

    Raises
    ------
    ReconstructionError
        Fewer than ``config.min_matches`` pairs found.
    """
    fa, fb = _tracked_features(sfm_a, allowed_a), _tracked_features(sfm_b, allowed_b)
    if not fa or not fb:
        raise ReconstructionError("cross matching: a model has no image with triangulated "
                                  "keypoints")
    partners = _similar_images(fa, fb, config.images_per_image, config.retrieval_sample, seed)
    votes: dict[tuple[int, int], int] = {}
    for name_a, names_b in partners.items():
        pa, da = fa[name_a]
        for name_b in names_b:
            pb, db = fb[name_b]
            ia, ib = _mutual_ratio(da, db, config.ratio)
            for key in zip(pa[ia].tolist(), pb[ib].tolist(), strict=True):
                votes[key] = votes.get(key, 0) + 1
    if not votes:
        raise ReconstructionError("cross matching: no SIFT matches between the two "
                                  "configurations; are both image sets of the same object?")
    keys = np.array(list(votes), dtype=np.int64)
    v = np.array(list(votes.values()), dtype=np.int64)
    # One-to-one: each 3D point keeps its most voted partner (ties: first in sorted order).
    order = np.lexsort((keys[:, 1], keys[:, 0], -v))
    keys, v = keys[order], v[order]
    _, first_a = np.unique(keys[:, 0], return_index=True)
    keep = np.zeros(len(keys), bool)
    keep[first_a] = True
    keys2, v2 = keys[keep], v[keep]
    order2 = np.lexsort((keys2[:, 0], keys2[:, 1], -v2))
    keys2, v2 = keys2[order2], v2[order2]
    _, first_b = np.unique(keys2[:, 1], return_index=True)
    keys, v = keys2[first_b], v2[first_b]
    good = v >= config.min_votes
    keys, v = keys[good], v[good]
    if len(keys) < config.min_matches:
        raise ReconstructionError(f"cross matching: only {len(keys)} 3D-3D matches between the "
                                  f"configurations (need {config.min_matches}); photograph both "
                                  "configurations from similar directions, with texture on every "
                                  "link")
    ra, rb = sfm_a.reconstruction, sfm_b.reconstruction
    pts_a = np.array([ra.points3D[int(i)].xyz for i in keys[:, 0]])
    pts_b = np.array([rb.points3D[int(i)].xyz for i in keys[:, 1]])
    cols = np.array([ra.points3D[int(i)].color for i in keys[:, 0]], dtype=np.uint8)
    log.info("cross matching: %d image pairs, %d 3D-3D matches (%d with >= 2 votes)",
             sum(len(x) for x in partners.values()), len(keys), int((v >= 2).sum()))
    return CrossMatches(pts_a, pts_b, keys[:, 0], keys[:, 1], v, cols)
