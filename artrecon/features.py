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
from scipy.spatial import cKDTree

from artrecon.errors import ReconstructionError
from artrecon.geometry import group_sums
from artrecon.workers import side_by_side

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


def tracked_features(sfm, allowed: set | None = None
                     ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per registered image: (point3D ids (k,), unit float descriptors (k, 128)) of the keypoints
    that belong to a 3D point (in ``allowed``, if given)."""
    rec = sfm.reconstruction
    out = {}
    with pycolmap.Database.open(sfm.database_path) as db:
        for img in rec.images.values():
            if not img.has_pose:
                continue
            # the keypoints with a 3D point (ascending), without visiting every keypoint
            points2D = img.points2D
            idx, pids = [], []
            for k in sorted(img.get_observation_point2D_idxs()):
                pid = points2D[k].point3D_id
                if allowed is None or pid in allowed:
                    idx.append(k)
                    pids.append(pid)
            if not idx:
                continue
            desc = db.read_descriptors(img.image_id)
            desc = np.asarray(desc.data if hasattr(desc, "data") else desc)
            pids = np.array(pids, dtype=np.int64)
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

    def rank(rows: range) -> list[list[str]]:
        out = []
        for i in rows:
            sim = sa[i] @ all_b.T
            scores = np.array([len(_mutual_ratio(sa[i], sb[j], 0.9,
                                                 sim[:, bounds[j]:bounds[j + 1]])[0])
                               for j in range(len(sb))])
            out.append([names_b[j] for j in np.argsort(-scores)[:k] if scores[j] > 0])
        return out

    # the images of A in two halves, side by side on the two cores (the run holds one BLAS
    # thread): each image's ranking is its own, so the result is the same
    half = len(names_a) // 2
    first, second = side_by_side(lambda: rank(range(half)),
                                 lambda: rank(range(half, len(names_a))))
    return dict(zip(names_a, first + second, strict=True))


def match_configurations(sfm_a, sfm_b, config: MatchConfig = MatchConfig(), seed: int = 0,
                         allowed_a: set | None = None, allowed_b: set | None = None,
                         features: tuple[dict, dict] | None = None) -> CrossMatches:
    """3D-3D matches between two SfM models of the object in configurations A and B.

    Parameters
    ----------
    sfm_a, sfm_b : artrecon.sfm.SfMResult
    config : MatchConfig
    seed : int
    allowed_a, allowed_b : set of int, optional
        Only these 3D point ids take part (e.g. the points on the object, not the background).
    features : (dict, dict), optional
        :func:`tracked_features` of the two models with these ``allowed`` ids, when the caller
        has them already.

    Returns
    -------
    CrossMatches

    Raises
    ------
    ReconstructionError
        Fewer than ``config.min_matches`` pairs found.
    """
    fa, fb = features if features is not None else (tracked_features(sfm_a, allowed_a),
                                                     tracked_features(sfm_b, allowed_b))
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


@dataclass
class PointDescriptors:
    """One SIFT descriptor per 3D point: the mean of its track's unit descriptors, normalised.

    Attributes
    ----------
    ids : (n,) int
        3D point ids of the SfM model.
    xyz : (n, 3) float
        Their positions.
    desc : (n, 128) float32
        Unit descriptors.
    """

    ids: np.ndarray
    xyz: np.ndarray
    desc: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


def point_descriptors(sfm, features: dict) -> PointDescriptors:
    """:class:`PointDescriptors` of the 3D points in ``features`` (:func:`tracked_features`)."""
    if not features:
        return PointDescriptors(np.zeros(0, np.int64), np.zeros((0, 3)),
                                np.zeros((0, 128), np.float32))
    pids = np.concatenate([f[0] for f in features.values()])
    desc = np.concatenate([f[1] for f in features.values()])
    ids, inv = np.unique(pids, return_inverse=True)
    sums = group_sums(inv, desc, len(ids))
    sums /= np.linalg.norm(sums, axis=1, keepdims=True) + 1e-12
    rec = sfm.reconstruction
    xyz = np.array([rec.points3D[int(i)].xyz for i in ids])
    return PointDescriptors(ids.astype(np.int64), xyz, sums.astype(np.float32))


@dataclass(frozen=True)
class GuidedConfig:
    """Settings of the guided matching (:func:`guided_matches`)."""

    enabled: bool = True
    """Add the guided matches to the segmented ones before the links' motions are final."""
    min_similarity: float = 0.85
    """Smallest cosine similarity of the two points' mean SIFT descriptors."""
    margin: float = 0.03
    """An A point is left out when a second candidate (another B point, or another link's
    prediction) is within this similarity of its best one: ambiguous."""
    rounds: int = 2
    """Rounds of guided matching and refitting (each with the refitted motions)."""


def guided_matches(transforms, radii, cand_a: PointDescriptors, cand_b: PointDescriptors,
                   config: GuidedConfig = GuidedConfig()) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
    """More 3D-3D matches, guided by each link's motion: SIFT points of A that the first
    matching left out (no mutual ratio-test match in any image pair) but whose position,
    moved by a link's motion, falls within that link's inlier distance of a B point with a
    similar descriptor.

    The first matching keeps only distinctive descriptors (Lowe's ratio over a whole image);
    once a link's motion is known, a point needs only be distinctive among the few B points
    near where that motion puts it. A point that two links' motions map onto plausible
    partners (near the joint, where the links move alike) or that has two similar candidates
    is left out.

    Parameters
    ----------
    transforms : list of Similarity
        Each link's motion A -> B.
    radii : list of float
        Each link's inlier distance (B units).
    cand_a, cand_b : PointDescriptors
        The A and B points that may be matched (not matched yet).
    config : GuidedConfig

    Returns
    -------
    idx_a, idx_b : (m,) int
        Indices into ``cand_a`` and ``cand_b`` of the new matches (one-to-one).
    link : (m,) int
        The link whose motion found each.
    """
    empty = (np.zeros(0, int), np.zeros(0, int), np.zeros(0, int))
    if len(cand_a) == 0 or len(cand_b) == 0 or not transforms:
        return empty

    tree = cKDTree(cand_b.xyz)
    n = len(cand_a)
    best_sim = np.full(n, -np.inf)
    second = np.full(n, -np.inf)
    best_b = np.full(n, -1)
    best_link = np.full(n, -1)
    for k, (T, r) in enumerate(zip(transforms, radii, strict=True)):
        moved = T.apply(cand_a.xyz)
        near = tree.query_ball_point(moved, r)
        for i, js in enumerate(near):
            for j in js:
                sim = float(cand_a.desc[i] @ cand_b.desc[j])
                # candidates are (link, B point) pairs: the same B point reached by two links'
                # motions competes with itself, so a point near the joint stays out
                if sim > best_sim[i]:
                    second[i] = best_sim[i]
                    best_sim[i], best_b[i], best_link[i] = sim, j, k
                elif sim > second[i]:
                    second[i] = sim
    # no second candidate at all (-inf): unambiguous
    gap = np.where(np.isfinite(second), best_sim - np.where(np.isfinite(second), second, 0.0),
                   np.inf)
    ok = (best_sim >= config.min_similarity) & (gap >= config.margin)
    ia = np.flatnonzero(ok)
    # one-to-one: a B point claimed twice goes to the more similar A point
    order = ia[np.argsort(-best_sim[ia], kind="stable")]
    _, first = np.unique(best_b[order], return_index=True)
    ia = np.sort(order[first])
    return ia, best_b[ia], best_link[ia]
