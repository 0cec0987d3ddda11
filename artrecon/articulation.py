"""Every step after matching: links, their dense points, the kinematic tree and the joints.

This module is the one place these steps and their order live, in two halves: :func:`find_links`
(the links stage, :mod:`artrecon.links_stage`) and :func:`find_joints` (the joints stage,
:mod:`artrecon.joints_stage`); :func:`articulate` runs both in one call, for the robustness
harness (``sim.perturb.resegment``, which re-runs them on corrupted matches)::

    find_links:
    check_motion (nothing moved? one body? other object?)    artrecon.diagnosis
    -> segment_links -> merge_equivalent_links               artrecon.segment, .link_motions
    -> anchor_base -> add_guided_matches -> robust_refit     artrecon.link_motions
    -> dense points the table is seen through dropped        artrecon.freespace
    -> dense points assigned to links                        artrecon.assign
    -> moving links' motions refitted with their surfaces     artrecon.surface_fit
    -> links without dense surface dropped, links_from_labels
    find_joints:
    build_kinematic_tree (rerooted at the base)              artrecon.joints
    -> estimate_joints -> assess_joints                      artrecon.joints, .confidence

In: the 3D-3D matches of the object and of the background (A's and B's frames), each
configuration's dense points and, optionally, its image cues. Out: :class:`Links`, then
:class:`JointSet` (:class:`Articulation`: both).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from artrecon import workers
from artrecon.assign import assign_dense_to_links
from artrecon.confidence import assess_joints
from artrecon.diagnosis import check_motion, explain_segmentation_failure
from artrecon.errors import DegenerateError, ReconstructionError
from artrecon.features import PointDescriptors
from artrecon.freespace import seen_through_table, support_plane
from artrecon.joints import KinematicTree, build_kinematic_tree, estimate_joints
from artrecon.link_motions import (
    add_guided_matches,
    anchor_base,
    fit_covariances,
    merge_equivalent_links,
    robust_refit,
)
from artrecon.match_refine import refine_link_matches
from artrecon.model import Link
from artrecon.segment import Segmentation, min_link_size, segment_links
from artrecon.settings import ReconstructConfig
from artrecon.surface_fit import surface_refit
from artrecon.uncertainty import MatchCovariances

log = logging.getLogger(__name__)


@dataclass
class Links:
    """What :func:`find_links` finds in the matches: the links, their motions and dense points
    (the links stage, :mod:`artrecon.links_stage`)."""

    segmentation: Segmentation
    """The matches' links, the base's motion anchored to the background."""
    root: int | None
    """The base (the link the background moves with), None when the background does not show it
    (the tree's root is then the largest link)."""
    anchors: dict | None
    """``{root: (background_a, background_b, weights[, precisions])}``: the background matches
    the base was fitted to, with their weights in the robust refit."""
    labels_a: np.ndarray
    """Link of each dense point of A (-1: none)."""
    labels_b: np.ndarray
    """Link of each dense point of B."""
    links: list[Link]
    points_a: np.ndarray
    """The matches the links were fitted to (the guided ones appended), A's frame ..."""
    points_b: np.ndarray
    """... and B's; ``segmentation.labels`` labels them."""
    guided_ids: np.ndarray
    """(m, 2) SfM point ids (A, B) of the matches the guided matching appended."""
    timings: dict[str, float]
    surface: list = field(default_factory=list)
    """Per moving link, what its surface refit did (:func:`artrecon.surface_fit.surface_refit`)."""
    refined: np.ndarray | None = None
    """Per match, whether its points were refined photometrically (:mod:`artrecon.match_refine`;
    None: not recorded)."""


@dataclass
class JointSet:
    """What :func:`find_joints` finds for the links: the kinematic tree, the joints and their
    evidence (the joints stage, :mod:`artrecon.joints_stage`)."""

    tree: KinematicTree
    joints: list
    confidence: dict
    """:func:`artrecon.confidence.assess_joints`' summary (each joint's record is also in
    ``Joint.confidence``)."""
    timings: dict[str, float]


@dataclass
class Articulation:
    """What :func:`articulate` finds in the matches: links, tree, joints and their evidence."""

    segmentation: Segmentation
    """The matches' links, the base's motion anchored to the background."""
    root: int | None
    """The base (the link the background moves with), None when the background does not show it
    (the tree's root is then the largest link)."""
    anchors: dict | None
    """``{root: (background_a, background_b, ...)}``: the background matches the base was
    fitted to."""
    labels_a: np.ndarray
    """Link of each dense point of A (-1: none)."""
    labels_b: np.ndarray
    """Link of each dense point of B."""
    links: list[Link]
    tree: KinematicTree
    joints: list
    confidence: dict
    """:func:`artrecon.confidence.assess_joints`' summary (each joint's record is also in
    ``Joint.confidence``)."""
    timings: dict[str, float]
    points_a: np.ndarray | None = None
    """The matches the links were fitted to (the guided ones appended), A's frame ..."""
    points_b: np.ndarray | None = None
    """... and B's; ``segmentation.labels`` labels them."""
    guided_ids: np.ndarray | None = None
    """(m, 2) SfM point ids (A, B) of the matches the guided matching appended."""

    @classmethod
    def of(cls, links: Links, joints: JointSet) -> Articulation:
        """The links and the joints found for them, as one."""
        return cls(links.segmentation, links.root, links.anchors, links.labels_a,
                   links.labels_b, links.links, joints.tree, joints.joints, joints.confidence,
                   {**links.timings, **joints.timings}, links.points_a, links.points_b,
                   links.guided_ids)


def articulate(points_a: np.ndarray, points_b: np.ndarray, background_a: np.ndarray,
               background_b: np.ndarray, dense_a, dense_b, config: ReconstructConfig, seed: int,
               *, views_a=None, views_b=None, occluders_a=None, occluders_b=None,
               candidates: tuple[PointDescriptors, PointDescriptors] | None = None,
               covariances: MatchCovariances | None = None) -> Articulation:
    """Every step after matching: segment the matches into links (method step 2), anchor the
    base to the background, label the dense points with links, build the kinematic tree on the
    links' dense points, estimate each joint (step 3) and check its evidence.

    :func:`find_links` then :func:`find_joints`, the steps the pipeline's links and joints
    stages run, in one call (sim.perturb.resegment re-runs them on corrupted matches).

    Parameters
    ----------
    points_a, points_b : (n, 3)
        The object's cross-configuration matches (A's and B's frames).
    background_a, background_b : (m, 3)
        Matches on the static background (may be empty).
    dense_a, dense_b : artrecon.dense.DensePoints
    views_a, views_b, occluders_a, occluders_b :
        The image cues of the dense labelling (artrecon.assign); without them the labelling is
        geometric only.
    candidates : (PointDescriptors, PointDescriptors), optional
        The object's SfM points of A and B that the matching left out, for the guided matching
        (:func:`artrecon.link_motions.add_guided_matches`, ``config.guided``); without them
        only the matches count.
    covariances : artrecon.uncertainty.MatchCovariances, optional
        The triangulation covariances of the matches', background matches' and candidates'
        points (row for row): the links' motions are then fitted with them
        (:func:`artrecon.link_motions.robust_refit`); without them (or with
        ``config.segmentation.covariances`` off), isotropically.

    Raises
    ------
    DegenerateError
        Fewer than two links (explained: no motion, one rigid body, chance pairings ...).
    WeakEvidenceError
        A joint's evidence is too weak for its axis (artrecon.confidence).
    """
    links = find_links(points_a, points_b, background_a, background_b, dense_a, dense_b,
                       config, seed, views_a=views_a, views_b=views_b, occluders_a=occluders_a,
                       occluders_b=occluders_b, candidates=candidates, covariances=covariances)
    return Articulation.of(links, find_joints(links, config, seed))


def find_links(points_a: np.ndarray, points_b: np.ndarray, background_a: np.ndarray,
               background_b: np.ndarray, dense_a, dense_b, config: ReconstructConfig, seed: int,
               *, views_a=None, views_b=None, occluders_a=None, occluders_b=None,
               candidates: tuple[PointDescriptors, PointDescriptors] | None = None,
               covariances: MatchCovariances | None = None, tracks=None) -> Links:
    """The first steps of :func:`articulate` (its parameters): the links, the base anchored to
    the background, the guided matches, the matches' points refined photometrically, the robust
    refit and the dense labels.

    ``tracks``: ``(reconstruction_a, reconstruction_b, point3D_ids_a, point3D_ids_b)``, the two
    SfM reconstructions (pycolmap) and the 3D point ids of ``points_a`` and ``points_b``; with
    them and the views, each link's matches are made one physical point in A and B
    (:func:`artrecon.match_refine.refine_link_matches`, ``config.photometric``); without them
    the SfM points are used as they are.

    Raises
    ------
    DegenerateError
        Fewer than two links (explained: no motion, one rigid body, chance pairings ...).
    """
    # One BLAS thread: these steps multiply many small matrices ((n, 3) points by a rotation),
    # for which a second BLAS thread only adds its start-up and spinning (40 ms instead of 1 ms
    # of CPU per product of 150k points on this 2-core machine); the results are the same. The
    # two configurations' work runs side by side instead.
    with workers.single_threaded():
        return _find_links(points_a, points_b, background_a, background_b, dense_a, dense_b,
                           config, seed, views_a=views_a, views_b=views_b,
                           occluders_a=occluders_a, occluders_b=occluders_b,
                           candidates=candidates, covariances=covariances, tracks=tracks)


def find_joints(links: Links, config: ReconstructConfig, seed: int) -> JointSet:
    """The last steps of :func:`articulate`: the kinematic tree on the links' dense points
    (rooted at the base), each joint, and its evidence.

    Raises
    ------
    WeakEvidenceError
        A joint's evidence is too weak for its axis (artrecon.confidence).
    """
    with workers.single_threaded():  # as find_links: many small products
        t = time.perf_counter()
        seg, root = links.segmentation, links.root
        # Adjacency on the links' dense surfaces: the matches are sparse where links meet.
        tree = build_kinematic_tree(links.points_a, seg, config.joints,
                                    link_points=[lk.points for lk in links.links])
        if root is None:
            log.warning("the background does not show which link is the base; the largest "
                        "link (%d) is taken as the root", tree.root)
        elif root != tree.root:
            tree = reroot(tree, root)
        joints = estimate_joints(links.points_a, links.points_b, seg, config.joints, tree=tree)
        # Evidence per joint (Joint.confidence); raises WeakEvidenceError rather than a wrong
        # axis.
        confidence = assess_joints(links.points_a, links.points_b, seg, joints, config.joints,
                                   config.confidence, seed, links.anchors)
        return JointSet(tree, joints, confidence, {"joints": time.perf_counter() - t})


def _find_links(points_a, points_b, background_a, background_b, dense_a, dense_b,
                config: ReconstructConfig, seed: int, *, views_a, views_b, occluders_a,
                occluders_b, candidates, covariances=None, tracks=None) -> Links:
    timings: dict[str, float] = {}
    t = time.perf_counter()
    # nothing moved, or the whole object did: said first and plainly (NoMotionError, ...), unless
    # so few of the object's points matched that B shows another object (the candidates are the
    # object's points the matching left out)
    object_points = None
    if candidates is not None:
        object_points = (len(points_a) + len(candidates[0].ids),
                         len(points_a) + len(candidates[1].ids))
    check_motion(points_a, points_b, background_a, background_b, config.segmentation, seed,
                 object_points=object_points)
    try:
        seg = segment_links(points_a, points_b, config.segmentation, seed=seed)
        seg = merge_equivalent_links(points_a, points_b, seg)
        if seg.n_links < 2:
            n = len(points_a)
            left = int((seg.labels < 0).sum())
            least = min_link_size(config.segmentation, n)
            raise DegenerateError(
                f"the matches form {seg.n_links} rigid link(s), an articulated object needs at "
                f"least 2: either the object moved as one rigid body (move a joint between the "
                f"two captures), or its moving part has too few matches to be found ({left} of "
                f"the {n} matches fit no link, a link needs at least {least}): photograph it "
                "with more views, in sharper images or with more texture on it.")
    except DegenerateError as exc:  # fewer than two links: one moving body, or other objects?
        raise explain_segmentation_failure(exc, points_a, points_b, config.segmentation,
                                           seed) from exc
    # The base moves with the room: its motion is fitted to the background matches too.
    seg, root, anchors = anchor_base(points_a, points_b, seg, background_a, background_b)
    guided = np.zeros((0, 2), np.int64)
    if candidates is not None and config.guided.enabled:
        points_a, points_b, seg, guided = add_guided_matches(points_a, points_b, seg, candidates,
                                                             anchors, config.guided)
    refined = np.zeros(len(points_a), bool)
    if (tracks is not None and config.photometric.enabled and views_a is not None
            and views_b is not None):
        # each match's two points made one physical point (artrecon.match_refine)
        t_photo = time.perf_counter()
        rec_a, rec_b, ids_a, ids_b = tracks
        points_a, points_b, refined = refine_link_matches(
            points_a, points_b, seg.labels, seg.transforms, np.r_[ids_a, guided[:, 0]],
            np.r_[ids_b, guided[:, 1]], rec_a, rec_b, views_a, views_b, dense_a,
            config.photometric)
        timings["photometric"] = time.perf_counter() - t_photo
        log.info("photometric refinement: %d of the %d matches of links refined (%.1f s)",
                 int(refined.sum()), int((np.asarray(seg.labels) >= 0).sum()),
                 timings["photometric"])
    refit_covariances = None
    if covariances is not None and config.segmentation.covariances:
        refit_covariances = fit_covariances(covariances, background_a, background_b, anchors,
                                            candidates, guided)
    seg, anchors = robust_refit(points_a, points_b, seg, anchors, refit_covariances)
    timings["segment"] = time.perf_counter() - t
    t = time.perf_counter()
    # dense points the table is seen through (fattened edges of thin links) join no link
    drop_a, drop_b = workers.side_by_side(
        lambda: table_free_space(dense_a.points, views_a, occluders_a, config, seed),
        lambda: table_free_space(dense_b.points, views_b, occluders_b, config, seed))
    # the table next to the object is static: Potts neighbours that move as the base does
    lab_a, lab_b = assign_dense_to_links(
        dense_a.subset(~drop_a), dense_b.subset(~drop_b), points_a, points_b, seg,
        views_a=views_a, views_b=views_b, occluders_a=occluders_a, occluders_b=occluders_b,
        config=config.assign, base=root, static_a=table_points(occluders_a, dense_a.points),
        static_b=table_points(occluders_b, dense_b.points))
    lab_a = _expand(lab_a, ~drop_a)
    lab_b = _expand(lab_b, ~drop_b)
    seg, root, anchors, lab_a, lab_b, unsupported = drop_unsupported_links(
        seg, root, anchors, lab_a, lab_b)
    if seg.n_links < 2:
        raise DegenerateError(
            f"of the {seg.n_links + len(unsupported)} links the matches form, only "
            f"{seg.n_links} holds any of the dense surface (the others' matches are "
            "chance pairings): the object moved as one rigid body, or its moving part was not "
            "seen well enough; photograph it with more views or more texture")
    timings["assign"] = time.perf_counter() - t
    t = time.perf_counter()
    # the moving links' motions pinned across their surfaces by their dense points
    seg, surface = surface_refit(seg, root, points_a, points_b, dense_a, dense_b, lab_a, lab_b,
                                 config.surface)
    timings["surface"] = time.perf_counter() - t
    links = links_from_labels(dense_a, dense_b, lab_a, lab_b, seg.transforms)
    return Links(seg, root, anchors, lab_a, lab_b, links, points_a, points_b, guided, timings,
                 surface, refined)


def drop_unsupported_links(seg: Segmentation, root: int | None, anchors: dict | None,
                           labels_a: np.ndarray, labels_b: np.ndarray):
    """Remove the links that the dense labelling gave no point of either configuration.

    Every link of the object has a surface the cameras saw (its matches are features on it), and
    the labelling offers each dense point to every link: a link that wins none is a set of
    matches that happen to move together (chance pairings on repeated texture, seen on
    pliers_panda: 21 matches, after sequential RANSAC split the mismatches into small "links"),
    not a part. Left in, it has no points to say where it meets the others (the kinematic tree
    cannot place it) and would become an invented joint. Its matches become outliers.

    Returns
    -------
    seg, root, anchors, labels_a, labels_b
        Renumbered (the remaining links keep their order).
    dropped : list of int
        The removed links, by their former numbers.
    """
    counts = (np.bincount(labels_a[labels_a >= 0], minlength=seg.n_links)[:seg.n_links]
              + np.bincount(labels_b[labels_b >= 0], minlength=seg.n_links)[:seg.n_links])
    dropped = [int(k) for k in np.flatnonzero(counts == 0)]
    if not dropped:
        return seg, root, anchors, labels_a, labels_b, dropped
    if root in dropped:
        raise ReconstructionError(f"the base link ({root}, the one the background moves with) "
                                  "holds none of the dense surface; reconstruct again with more "
                                  "views of the object")
    keep = [k for k in range(seg.n_links) if k not in dropped]
    remap = np.full(seg.n_links + 1, -1)  # the last entry maps -1 to -1
    remap[keep] = np.arange(len(keep))
    for k in dropped:
        log.warning("link %d (%d matches) holds none of the dense surface of A or B: dropped, "
                    "its matches taken for chance pairings", k, int(seg.sizes[k]))

    def pick(values):
        return [values[k] for k in keep] if values else values

    seg = replace(seg, labels=remap[seg.labels], transforms=pick(seg.transforms),
                  thresholds=pick(seg.thresholds), rms=pick(seg.rms))
    if anchors:
        anchors = {int(remap[k]): v for k, v in anchors.items() if k in keep}
    root = None if root is None else int(remap[root])
    return seg, root, anchors, remap[labels_a], remap[labels_b], dropped


def table_free_space(points: np.ndarray, views, occluders, config: ReconstructConfig,
                     seed: int) -> np.ndarray:
    """Mask (n,) of the dense points of one configuration that its views see the table through
    (:func:`artrecon.freespace.seen_through_table`); none without colour views or occluders (the
    dense points the support plane is fitted to, as the object region fits it)."""
    drop = np.zeros(len(points), bool)
    if (not config.freespace.enabled or not views or occluders is None or len(points) == 0
            or any(v.colour is None for v in views)):
        return drop
    centres = np.array([v.centre for v in views])
    axes = np.array([v.T_cw[2, :3] for v in views])
    r = config.region
    plane = support_plane(occluders, centres, axes, radius_fraction=r.radius_fraction,
                          tolerance=r.plane_tolerance, min_fraction=r.plane_min_fraction,
                          iterations=r.plane_iterations, seed=seed)
    return seen_through_table(points, views, plane, config.freespace, seed)


def table_points(occluders: np.ndarray | None, object_points: np.ndarray) -> np.ndarray | None:
    """The dense points of one configuration that the object region took for the background
    (``occluders``, all its dense points, less the object's ``object_points``). Next to the object
    these are the table it stands on (and the base's lowest millimetres, cut with the table):
    static, they move as the base does. None without occluders."""
    if occluders is None or len(occluders) == 0:
        return None
    occluders = np.asarray(occluders, float)
    if len(object_points) == 0:
        return occluders
    # the object's points are the same numbers in both arrays (artrecon.configuration); if they
    # are not (occluders from elsewhere), the object's own surface would pass for the table
    # (only equal points matter: a tiny search bound spares the far table a full search,
    # 0.2 instead of 17 CPU s for the 0.9 M occluders of scissors)
    d = cKDTree(np.asarray(object_points, float)).query(occluders, distance_upper_bound=1e-12)[0]
    if np.count_nonzero(d == 0) < 0.5 * len(object_points):
        log.warning("the occluders do not hold the object's dense points; the table is left out "
                    "of the dense labelling")
        return None
    return occluders[d > 0]


def _expand(labels: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """Labels of the kept points spread back over all points (-1: dropped)."""
    out = np.full(len(kept), -1, dtype=np.asarray(labels).dtype if len(labels) else int)
    out[kept] = labels
    return out


def reroot(tree: KinematicTree, root: int) -> KinematicTree:
    """The same tree with another root (edges re-oriented, breadth-first from the new root)."""
    n = len(tree.parents)
    nbrs: dict[int, list[int]] = {k: [] for k in range(n)}
    for p, c in tree.edges:
        nbrs[p].append(c)
        nbrs[c].append(p)
    parents = np.full(n, -1)
    edges, queue, seen = [], [root], {root}
    while queue:
        u = queue.pop(0)
        for v in sorted(nbrs[u]):
            if v not in seen:
                seen.add(v)
                parents[v] = u
                edges.append((u, v))
                queue.append(v)
    # the pairs' figures, costs and margin do not depend on the root
    return replace(tree, root=root, parents=parents, edges=edges)


def links_from_labels(dense_a, dense_b, labels_a: np.ndarray, labels_b: np.ndarray,
                      transforms) -> list[Link]:
    """The links of a model from its labelled dense points (configuration A's frame).

    Link k holds the points of A labelled k and the points of B labelled k carried back into A
    by the inverse of its transform: together, the link as both configurations saw it (what one
    of them hid, the other may show). ``Link.observed_in`` says which configuration saw each.

    Parameters
    ----------
    dense_a, dense_b : artrecon.dense.DensePoints
    labels_a, labels_b : (len(dense_a),), (len(dense_b),) int
        Link per point (artrecon.assign).
    transforms : sequence of Similarity
        Each link's A -> B transform.
    """
    links = []
    for k, T in enumerate(transforms):
        ia, ib = labels_a == k, labels_b == k
        pts = np.concatenate([dense_a.points[ia], T.inverse().apply(dense_b.points[ib])])
        nrm = np.concatenate([dense_a.normals[ia], dense_b.normals[ib] @ T.rotation])
        col = np.concatenate([dense_a.colors[ia], dense_b.colors[ib]])
        seen = np.concatenate([np.zeros(int(ia.sum()), np.int8), np.ones(int(ib.sum()), np.int8)])
        links.append(Link(points=pts, match_indices=np.full(len(pts), -1), transform_a_to_b=T,
                          colours=col, normals=nrm, name=f"link_{k}", observed_in=seen))
    return links
