"""Joints between rigid links: kinematic tree, joint type, axis and joint-state change.

Input: the matches and their `Segmentation` (per link a similarity A -> B, sharing one scale).
For a parent P and child C the child's motion relative to the parent, in the model frame
(configuration A), is T_rel = T_P^-1 T_C: the parent's own motion (and the change of SfM frame)
cancels. Then, as in the method:

- type: revolute when the rotation angle of T_rel exceeds `revolute_min_angle`, else prismatic;
- revolute axis: direction u = the rotation's fixed vector (eigenvector of eigenvalue 1, via the
  rotation vector); point: the rotation centre in the plane normal to u, from t = (I - R) p solved
  in closed form p = (t_perp + cot(theta/2) u x t_perp) / 2 (well conditioned for any theta above
  the threshold), moved along the axis next to the child's centroid;
- prismatic axis: direction of the child's mean displacement, through the smaller link's centroid;
- state: configuration A is the zero; state_b = the angle (rad) or displacement (model units).

Links are joined into a tree rooted at the largest link: a minimum spanning tree over the pairs of
spatially adjacent links (closest points in configuration A within `adjacency_distance` x scene
size). Each pair is scored by how well ONE joint located where the two links touch explains their
relative motion: the cost of the edge is the sum, relative to the scene size, of

- the gap between the links (robust closest-point distance);
- the single-joint misfit (`single_joint_misfit`): the slide along the axis of a revolute motion
  (a screw is not one hinge), the residual rotation of a prismatic one;
- for a revolute motion, how far its axis passes from the links' contact region (`contact_points`:
  the points of each link within the gap plus `CONTACT_MARGIN` x scene size of the other; the
  distance is `axis_gap` of those points): a hinge's pin runs through the place where its two
  links meet. A prismatic motion has no axis position, so no such term.

The axis term tells siblings from parent and child. Two fingers of the Barrett hand each turn on
the palm about its own (parallel) spread axis; their motion relative to each other is then a clean
rotation too (by the sum of the two angles, no slide), about an axis between the fingers. With
a few stray labels where the fingers face each other they even look as close to each other as to
the palm, whose surface under the knuckles is hidden. But that axis runs 2 cm from the few points
where the fingers come near each other, while each finger's true axis runs through its knuckle,
ringed by the points where knuckle and palm meet (about 1.2 cm, the knuckle's half-width). The
same term tells a planar chain: in the scraper truck (boom on the chassis, blade on the boom,
parallel hinges) the blade's motion relative to the chassis is also a clean rotation, and the
blade hangs as close to the chassis as to the boom; but that rotation's axis runs centimetres
away from where they meet, while the true hinges run through it.

`KinematicTree.edge_figures` keeps every candidate pair's figures and `KinematicTree.margin` how
much cheaper the chosen tree is than the best other spanning tree (logged).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from artrecon import tolerances as tol
from artrecon.errors import DegenerateError, ReconstructionError
from artrecon.geometry import axis_angle, rotation_angle
from artrecon.model import Joint
from artrecon.procrustes import Similarity

log = logging.getLogger(__name__)

__all__ = [
    "JointConfig",
    "KinematicTree",
    "axis_gap",
    "build_kinematic_tree",
    "contact_points",
    "estimate_joints",
    "joint_from_motion",
    "relative_motion",
    "single_joint_misfit",
]


#: The contact region of two adjacent links (where a joint between them must run; see
#: `contact_points`) is the points of each within their gap plus this fraction of the scene size
#: of the other: a band a few point spacings wide along the seam (3 mm on the 6 cm Barrett hand,
#: whose dense points are about 1 mm apart). The hand's tree is the same from 0 (the gap alone)
#: to 0.2; a band as wide as the links takes in all of them, and the axis term then measures the
#: axis' distance from the links as wholes, which chains the hand's fingers. (Here, not in
#: artrecon.tolerances: that module is part of the per-configuration stage's code, whose cache
#: key an edit of it would change.)
CONTACT_MARGIN = 0.05


@dataclass(frozen=True)
class JointConfig:
    """Joint estimation settings; lengths are fractions of the scene size of configuration A."""

    revolute_min_angle: float = tol.REVOLUTE_MIN_ANGLE
    """Rotation angle (rad) of the relative motion above which a joint is revolute."""
    adjacency_distance: float = tol.ADJACENCY_DISTANCE
    """Links whose closest points are nearer than this x scene size may share a joint."""
    misfit_weight: float = tol.MISFIT_WEIGHT
    """Weight of the single-joint misfit (relative to scene size) in the tree edge cost."""
    axis_gap_weight: float = 1.0
    """Weight of the revolute axis' distance from the two links' contact region (relative to
    scene size) in the tree edge cost (see `contact_points` and `axis_gap`)."""
    contact_margin: float = CONTACT_MARGIN
    """The contact region of two links: the points of each within their gap plus this x scene
    size of the other (see `contact_points`)."""


@dataclass
class KinematicTree:
    """Which link is attached to which.

    Attributes
    ----------
    root : int
        The largest link.
    parents : (n_links,) int
        Parent of each link, -1 for the root.
    edges : list of (parent, child)
        In breadth-first order from the root.
    gaps : (n_links, n_links) float
        Closest-point distance between every two links (configuration A, model units).
    costs : (n_links, n_links) float
        Edge cost of every adjacent pair (relative to scene size; 0: not adjacent).
    edge_figures : dict (i, j) -> dict, i < j
        Per adjacent pair: ``gap``, ``misfit``, ``axis_contact`` (model units), ``angle_deg``,
        ``type``, ``contact`` (contact points of i and j), ``cost``, ``in_tree``.
    margin : float
        Cost of the best spanning tree other than the chosen one minus the chosen tree's
        (relative to scene size; inf when there is no other): how clearly the tree is chosen.
    """

    root: int
    parents: np.ndarray
    edges: list[tuple[int, int]] = field(default_factory=list)
    gaps: np.ndarray | None = None
    costs: np.ndarray | None = None
    edge_figures: dict = field(default_factory=dict)
    margin: float = float("inf")

    def children(self, link: int) -> list[int]:
        return [c for p, c in self.edges if p == link]


def relative_motion(t_parent: Similarity, t_child: Similarity) -> Similarity:
    """Motion of the child relative to the parent in the model frame: T_parent^-1 T_child."""
    return t_parent.inverse() @ t_child


def single_joint_misfit(
    motion: Similarity, child_points: np.ndarray, revolute_min_angle: float
) -> tuple[str, float]:
    """Classify a relative motion and measure how far it is from one pure joint.

    Parameters
    ----------
    motion : Similarity
        Relative motion of the child (model frame).
    child_points : (n, 3) float
        The child's points, configuration A.
    revolute_min_angle : float
        Rotation angle (rad) above which the motion is revolute.

    Returns
    -------
    type : str
        "revolute" or "prismatic".
    misfit : float
        Model units. Revolute: |slide along the axis| (a screw motion is not one joint).
        Prismatic: RMS displacement of the child's points caused by the residual rotation.
    """
    u, theta = axis_angle(motion.rotation)
    if theta >= revolute_min_angle:
        return "revolute", abs(float(motion.translation @ u))
    centred = child_points - child_points.mean(axis=0)
    rot_disp = centred @ (motion.scale * motion.rotation - np.eye(3)).T
    return "prismatic", float(np.sqrt(np.mean(np.einsum("ij,ij->i", rot_disp, rot_disp))))


def joint_from_motion(
    motion: Similarity,
    parent: int,
    child: int,
    parent_points: np.ndarray,
    child_points: np.ndarray,
    config: JointConfig = JointConfig(),  # noqa: B008 (frozen, immutable)
) -> Joint:
    """Joint type, axis and state change from the child's motion relative to its parent.

    Parameters
    ----------
    motion : Similarity
        T_parent^-1 T_child (model frame).
    parent, child : int
        Link indices.
    parent_points, child_points : (n, 3) float
        Configuration-A points of the two links (centroids and sizes).
    config : JointConfig

    Returns
    -------
    Joint
    """
    kind, misfit = single_joint_misfit(motion, child_points, config.revolute_min_angle)
    c_child = child_points.mean(axis=0)
    if kind == "revolute":
        u, theta = axis_angle(motion.rotation)
        t = motion.translation
        t_perp = t - (t @ u) * u
        # Rotation about the axis through p: t = (I - R) p. In the plane normal to u this inverts
        # in closed form; cot(theta/2) is bounded because theta >= revolute_min_angle.
        p = 0.5 * (t_perp + np.cross(u, t_perp) / np.tan(0.5 * theta))
        p = p + ((c_child - p) @ u) * u
        return Joint("revolute", u, p, parent, child, 0.0, theta, relative_transform=motion,
                     residual=misfit)
    displacement = motion.apply(c_child) - c_child
    dist = float(np.linalg.norm(displacement))
    if dist == 0.0:
        raise DegenerateError(
            f"links {parent} and {child} did not move relative to each other; they are one rigid "
            "body. Re-run the segmentation (or move the joint between the captures)."
        )
    smaller = child_points if len(child_points) <= len(parent_points) else parent_points
    return Joint("prismatic", displacement / dist, smaller.mean(axis=0), parent, child, 0.0, dist,
                 relative_transform=motion, residual=misfit)


def _link_points(points_a: np.ndarray, segmentation) -> list[np.ndarray]:
    return [points_a[segmentation.labels == k] for k in range(segmentation.n_links)]


def build_kinematic_tree(
    points_a: np.ndarray,
    segmentation,
    config: JointConfig = JointConfig(),  # noqa: B008 (frozen, immutable)
    link_points: list[np.ndarray] | None = None,
) -> KinematicTree:
    """Kinematic tree over the links, rooted at the largest link.

    Parameters
    ----------
    points_a : (n, 3) float
        The matches' points in configuration A (those given to segment_links). They set the
        scene size.
    segmentation : Segmentation
    config : JointConfig
    link_points : list of (m_k, 3) float, optional
        Each link's points in configuration A to measure the gaps, misfits and axis distances on:
        the dense points assigned to the links (artrecon.reconstruct does so). The matches are
        sparse where links meet (a long boom may carry no match near the hinge at its far end),
        so their gaps are only an upper bound; the links' dense surfaces touch. Default: the
        matches of each link.

    Returns
    -------
    KinematicTree

    Raises
    ------
    SingleBodyError-like DegenerateError
        Fewer than two links.
    ReconstructionError
        Some link is not adjacent to any other (the adjacency graph is disconnected).
    """
    points_a = _check_points(points_a, segmentation)
    n_links = segmentation.n_links
    if n_links < 2:
        raise DegenerateError(
            f"build_kinematic_tree needs at least 2 links, the segmentation has {n_links}: the "
            "object moved as one rigid body. Move a joint between the two captures."
        )
    if link_points is None:
        pts = _link_points(points_a, segmentation)
    else:
        if len(link_points) != n_links:
            raise ValueError(f"link_points has {len(link_points)} links, the segmentation "
                             f"{n_links}")
        pts = [_subsample(np.asarray(p, dtype=float).reshape(-1, 3)) for p in link_points]
        empty = [k for k, p in enumerate(pts) if len(p) == 0]
        if empty:
            raise ReconstructionError(f"build_kinematic_tree: links {empty} have no points")
    size = tol.scene_size(points_a[segmentation.labels >= 0])
    trees = [cKDTree(p) for p in pts]
    t = segmentation.transforms
    gaps = np.zeros((n_links, n_links))
    cost = np.zeros((n_links, n_links))
    figures: dict[tuple[int, int], dict] = {}
    for i in range(n_links):
        for j in range(i + 1, n_links):
            d_i, _ = trees[j].query(pts[i], k=1)  # each point of i to link j
            d_j, _ = trees[i].query(pts[j], k=1)
            gaps[i, j] = gaps[j, i] = _robust_gap(d_i, d_j)
            if gaps[i, j] > config.adjacency_distance * size:
                continue
            motion = relative_motion(t[i], t[j])
            # Misfit in both directions (which link is the child is not known yet); the smaller.
            kind, m_ij = single_joint_misfit(motion, pts[j], config.revolute_min_angle)
            m_ji = single_joint_misfit(relative_motion(t[j], t[i]), pts[i],
                                       config.revolute_min_angle)[1]
            c_i, c_j = contact_points(pts[i], pts[j], d_i, d_j, gaps[i, j],
                                      config.contact_margin * size)
            a_gap = axis_gap(motion, c_i, c_j, config.revolute_min_angle)
            w = (gaps[i, j] + config.misfit_weight * min(m_ij, m_ji)
                 + config.axis_gap_weight * a_gap) / size
            cost[i, j] = cost[j, i] = w + 1e-12  # csgraph treats 0 as "no edge"
            figures[(i, j)] = {
                "type": kind, "gap": float(gaps[i, j]), "misfit": float(min(m_ij, m_ji)),
                "axis_contact": float(a_gap),
                "angle_deg": float(np.degrees(rotation_angle(motion.rotation))),
                "contact": (len(c_i), len(c_j)), "cost": float(w)}
    n_comp, comp = connected_components(cost, directed=False)
    if n_comp > 1:
        lonely = [int(k) for k in range(n_links) if np.sum(comp == comp[k]) < n_links]
        raise ReconstructionError(
            f"build_kinematic_tree: the {n_links} links form {n_comp} groups that are not within "
            f"{config.adjacency_distance:g} x scene size of each other (links {lonely}; closest "
            f"gaps {np.round(gaps / size, 3).tolist()} x scene size). A link far from every other "
            "is not attached by a joint: check the segmentation, or raise "
            "JointConfig.adjacency_distance."
        )
    mst = minimum_spanning_tree(cost)
    tree_pairs = {tuple(sorted((int(a), int(b)))) for a, b in zip(*mst.nonzero(), strict=True)}
    mst = mst + mst.T
    sizes = segmentation.sizes
    root = int(np.argmax(sizes))
    order, preds = breadth_first_order(mst, root, directed=False, return_predecessors=True)
    parents = np.where(preds < 0, -1, preds).astype(np.int64)
    parents[root] = -1
    edges = [(int(parents[c]), int(c)) for c in order if c != root]
    margin = _tree_margin(cost, tree_pairs)
    for pair, fig in figures.items():
        fig["in_tree"] = pair in tree_pairs
        log.info("tree edge %d-%d%s: %s, gap %.3g, misfit %.3g, axis to contact %.3g (model "
                 "units), relative angle %.2f deg, contact %d/%d points; cost %.4f x scene size",
                 pair[0], pair[1], " (in tree)" if fig["in_tree"] else "", fig["type"],
                 fig["gap"], fig["misfit"], fig["axis_contact"], fig["angle_deg"],
                 *fig["contact"], fig["cost"])
    log.info("kinematic tree %s (root %d), margin over the next best tree %.4f x scene size",
             edges, root, margin)
    return KinematicTree(root=root, parents=parents, edges=edges, gaps=gaps, costs=cost,
                         edge_figures=figures, margin=margin)


def contact_points(points_i: np.ndarray, points_j: np.ndarray, dist_i: np.ndarray,
                   dist_j: np.ndarray, gap: float, margin: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The contact region of two links: the points of each within ``gap + margin`` of the other.

    Where two links are jointed they meet; the points near the other link surround the joint
    (a knuckle's rim on the palm, a hinge's edge), even when the joint itself is hidden.

    Parameters
    ----------
    points_i, points_j : (n, 3), (m, 3) float
        The two links' points, configuration A.
    dist_i, dist_j : (n,), (m,) float
        Each point's distance to the nearest point of the other link.
    gap : float
        The links' robust gap (`_robust_gap` of the two distance sets).
    margin : float
        Model units.

    Returns
    -------
    (n_i, 3), (n_j, 3) float
        Each link's contact points; not empty (the robust gap has at least
        ``ADJACENCY_ROBUST_K`` points of each link within it).
    """
    r = gap + margin
    return points_i[dist_i <= r], points_j[dist_j <= r]


def _tree_margin(cost: np.ndarray, tree_pairs: set[tuple[int, int]]) -> float:
    """Cost of the cheapest spanning tree other than the minimum one, minus the minimum's.

    The second-best spanning tree differs from the minimum one by one swap: a non-tree edge in,
    the dearest tree edge on the cycle it closes out. inf when no other tree exists."""
    n = len(cost)
    nbrs: dict[int, list[int]] = {k: [] for k in range(n)}
    for a, b in tree_pairs:
        nbrs[a].append(b)
        nbrs[b].append(a)

    def path_max(a: int, b: int) -> float:  # dearest edge on the tree path a .. b
        stack = [(a, -1, 0.0)]
        while stack:
            u, prev, worst = stack.pop()
            if u == b:
                return worst
            stack.extend((v, u, max(worst, cost[u, v])) for v in nbrs[u] if v != prev)
        return float("inf")

    best = float("inf")
    for a in range(n):
        for b in range(a + 1, n):
            if cost[a, b] > 0 and (a, b) not in tree_pairs:
                best = min(best, float(cost[a, b] - path_max(a, b)))
    return best


def axis_gap(motion: Similarity, points_i: np.ndarray, points_j: np.ndarray,
             revolute_min_angle: float) -> float:
    """How far the axis of a revolute relative motion passes from the farther of two point sets.

    A hinge joins two links through its pin, so its axis passes through (or next to) both, and
    through the region where they meet (build_kinematic_tree passes each link's `contact_points`).
    The distance of the axis line to a point set is the k-th smallest distance of its points to
    the line (the robust k of the gap between links). 0 for a prismatic motion (its axis position
    means nothing).

    Parameters
    ----------
    motion : Similarity
        Relative motion of link j to link i (either way round: the same axis line).
    points_i, points_j : (n, 3) float
        Points of the two links (all of them, or their contact points), configuration A.
    revolute_min_angle : float

    Returns
    -------
    float
        Model units.
    """
    u, theta = axis_angle(motion.rotation)
    if theta < revolute_min_angle:
        return 0.0
    t = motion.translation
    t_perp = t - (t @ u) * u
    p = 0.5 * (t_perp + np.cross(u, t_perp) / np.tan(0.5 * theta))
    out = 0.0
    for pts in (points_i, points_j):
        v = pts - p
        d = np.linalg.norm(v - np.outer(v @ u, u), axis=1)
        k = _robust_k(len(d))
        out = max(out, float(np.partition(d, k)[k]))
    return out


#: Dense link points measured per link in build_kinematic_tree (a fixed subsample above this).
TREE_MAX_POINTS = 20000


def _subsample(points: np.ndarray) -> np.ndarray:
    if len(points) <= TREE_MAX_POINTS:
        return points
    idx = np.random.default_rng(0).choice(len(points), TREE_MAX_POINTS, replace=False)
    return points[np.sort(idx)]


def _robust_k(n: int) -> int:
    """Index of the robust smallest of n distances: ADJACENCY_ROBUST_K for sparse matches, a
    share (ADJACENCY_ROBUST_SHARE) of a dense link's points, whose labels have more strays."""
    return min(max(tol.ADJACENCY_ROBUST_K, int(np.ceil(tol.ADJACENCY_ROBUST_SHARE * n))), n) - 1


def _robust_gap(dist_i: np.ndarray, dist_j: np.ndarray) -> float:
    """Closest-point distance between two links, ignoring a few stray points (the k-th smallest
    nearest-neighbour distance, k from `_robust_k`, in both directions), from each link's points'
    distances to the other link."""
    gaps = []
    for d in (dist_i, dist_j):
        k = _robust_k(len(d))
        gaps.append(float(np.partition(d, k)[k]))
    return max(gaps)


def _check_points(points_a, segmentation) -> np.ndarray:
    points_a = np.asarray(points_a, dtype=float)
    if points_a.ndim != 2 or points_a.shape[1] != 3:
        raise ValueError(f"points_a must have shape (n, 3), got {points_a.shape}")
    if len(segmentation.labels) != len(points_a):
        raise ValueError(
            f"segmentation has {len(segmentation.labels)} labels but points_a has "
            f"{len(points_a)} points; pass the matches given to segment_links"
        )
    return points_a


def estimate_joints(
    points_a: np.ndarray,
    points_b: np.ndarray,
    segmentation,
    config: JointConfig = JointConfig(),  # noqa: B008 (frozen, immutable)
    tree: KinematicTree | None = None,
) -> list[Joint]:
    """One joint per non-root link of the kinematic tree (breadth-first from the root).

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        The matches given to segment_links (points_b is checked for shape only: the link
        transforms already carry configuration B).
    segmentation : Segmentation
    config : JointConfig
    tree : KinematicTree, optional
        Computed with build_kinematic_tree when not given.

    Returns
    -------
    list of Joint
        joint.parent / joint.child index segmentation's links; the root is the largest link.
    """
    points_a = _check_points(points_a, segmentation)
    points_b = np.asarray(points_b, dtype=float)
    if points_b.shape != points_a.shape:
        raise ValueError(f"points_b must have shape {points_a.shape}, got {points_b.shape}")
    if tree is None:
        tree = build_kinematic_tree(points_a, segmentation, config)
    pts = _link_points(points_a, segmentation)
    joints = []
    for parent, child in tree.edges:
        motion = relative_motion(segmentation.transforms[parent], segmentation.transforms[child])
        joint = joint_from_motion(motion, parent, child, pts[parent], pts[child], config)
        log.info(
            "joint %s: %s, %s %.4g, residual %.3g, angle of relative rotation %.2f deg",
            joint.name, joint.type, "angle" if joint.type == "revolute" else "displacement",
            joint.state_b, joint.residual, np.degrees(rotation_angle(motion.rotation)),
        )
        joints.append(joint)
    return joints
