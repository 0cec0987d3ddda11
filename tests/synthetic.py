"""Synthetic articulated objects with known links, joints and matches (test helper, not a test).

A root box at the origin; each child box is attached to a face of its parent through a random
revolute or prismatic joint. Configuration A is the world frame; configuration B is the moved object
seen through a random similarity (the second SfM model's arbitrary frame and scale). Ground truth
axes are in configuration A's frame, the same frame `artrecon.joints` reports in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from artrecon.procrustes import Similarity

#: Root box half extents and where children attach: (face normal, half extents of the child).
ROOT_HALF = np.array([0.5, 0.3, 0.08])
CHILD_HALF = np.array([0.25, 0.2, 0.06])
GAP = 0.02

#: structure name -> parent of links 1.. (link 0 is the root)
STRUCTURES = {
    "pair": [0],
    "chain": [0, 1],
    "star": [0, 0],
}


@dataclass
class TrueJoint:
    type: str
    parent: int
    child: int
    axis_direction: np.ndarray
    axis_point: np.ndarray
    value: float  # angle (rad) or displacement (world units), configuration A -> B


@dataclass
class SyntheticObject:
    points_a: np.ndarray  # (n, 3) matches, configuration A (world)
    points_b: np.ndarray  # (n, 3) matches, configuration B (its own similarity frame)
    labels: np.ndarray  # (n,) true link of each match, -1 for outlier matches
    joints: list[TrueJoint]
    link_motions: list[Similarity]  # per link, A -> B
    frame_b: Similarity  # world -> configuration B frame
    noise: float  # Gaussian sigma, world units, per axis


def _box(rng, centre, half, n):
    return centre + rng.uniform(-half, half, size=(n, 3))


def _unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def make_object(
    seed: int,
    structure: str = "pair",
    joint_types: tuple[str, ...] = ("revolute",),
    points_per_link: int = 80,
    noise: float = 0.0,
    outlier_fraction: float = 0.0,
    min_angle_deg: float = 15.0,
) -> SyntheticObject:
    """Random articulated object and its noisy 3D-3D matches.

    Parameters
    ----------
    seed : int
    structure : "pair" | "chain" | "star"
        2 links; 3 links 0-1-2; 3 links with two children of the root.
    joint_types : tuple of str
        Type of each joint (cycled).
    points_per_link : int
    noise : float
        Gaussian sigma (world units; the root box is 1 x 0.6 x 0.16) on every matched point, in
        both configurations (in B, scaled by the similarity).
    outlier_fraction : float
        Fraction of all matches that are wrong (a's point paired with a random other B point).
    min_angle_deg : float
        Smallest revolute motion.
    """
    rng = np.random.default_rng(seed)
    parents = STRUCTURES[structure]
    n_links = len(parents) + 1
    centres = [np.zeros(3)]
    halves = [ROOT_HALF]
    # children on +x of their parent, or -x of the root for the second child of a star
    used_minus_x = False
    for k, p in enumerate(parents, start=1):
        side = 1.0
        if structure == "star" and p == 0 and k == 2 and not used_minus_x:
            side = -1.0
            used_minus_x = True
        c = centres[p] + side * np.array([halves[p][0] + GAP + CHILD_HALF[0], 0.0, 0.0])
        c[1] += rng.uniform(-0.05, 0.05)
        centres.append(c)
        halves.append(CHILD_HALF)
    joint_motions = [Similarity()]  # joint motion of each link relative to its parent (frame A)
    joints = []
    for k, p in enumerate(parents, start=1):
        jtype = joint_types[(k - 1) % len(joint_types)]
        side = np.sign(centres[k][0] - centres[p][0])
        face_x = centres[p][0] + side * (halves[p][0] + 0.5 * GAP)
        point = np.array([face_x, centres[k][1] + rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05)])
        direction = _unit(rng)
        if jtype == "revolute":
            angle = np.deg2rad(rng.uniform(min_angle_deg, 120.0)) * rng.choice([-1.0, 1.0])
            rot = Rotation.from_rotvec(angle * direction).as_matrix()
            motion = Similarity(rot, point - rot @ point, 1.0)
            value = angle
        else:
            value = rng.uniform(0.1, 0.4)
            motion = Similarity(np.eye(3), value * direction, 1.0)
        joints.append(TrueJoint(jtype, p, k, direction, point, value))
        joint_motions.append(motion)
    # the whole object also moved a little, and configuration B has its own frame and scale
    root_motion = Similarity(
        Rotation.from_rotvec(rng.uniform(-0.3, 0.3, 3)).as_matrix(), rng.uniform(-0.2, 0.2, 3), 1.0
    )
    frame_b = Similarity(
        Rotation.random(random_state=int(rng.integers(2**31))).as_matrix(),
        rng.uniform(-5, 5, 3),
        float(np.exp(rng.uniform(np.log(0.3), np.log(3.0)))),
    )
    link_motions = []
    for k in range(n_links):
        m = joint_motions[k]
        p = parents[k - 1] if k > 0 else None
        while p is not None:
            m = joint_motions[p] @ m
            p = parents[p - 1] if p > 0 else None
        link_motions.append(frame_b @ root_motion @ m)
    pa_list, pb_list, labels = [], [], []
    for k in range(n_links):
        count = 2 * points_per_link if k == 0 else points_per_link  # the root is the largest
        pts = _box(rng, centres[k], halves[k], count)
        pa_list.append(pts + noise * rng.normal(size=pts.shape))
        pb_list.append(
            link_motions[k].apply(pts) + frame_b.scale * noise * rng.normal(size=pts.shape)
        )
        labels.append(np.full(count, k))
    pa = np.vstack(pa_list)
    pb = np.vstack(pb_list)
    lab = np.concatenate(labels)
    n_in = len(pa)
    n_out = int(round(outlier_fraction / (1.0 - outlier_fraction) * n_in))
    if n_out:
        ia = rng.integers(0, n_in, n_out)
        ib = rng.integers(0, n_in, n_out)
        same = ia == ib
        ib[same] = (ib[same] + 1) % n_in
        pa = np.vstack([pa, pa[ia]])
        pb = np.vstack([pb, pb[ib]])
        lab = np.concatenate([lab, np.full(n_out, -1)])
    perm = rng.permutation(len(pa))
    return SyntheticObject(pa[perm], pb[perm], lab[perm], joints, link_motions, frame_b, noise)


def box_surface(rng, lo, hi, density: float, skip: tuple[str, ...] = ()) -> np.ndarray:
    """Points sampled uniformly on the faces of the box [lo, hi] (about `density` per unit area),
    as dense stereo sees a solid: its surface only. `skip` leaves faces out ("-z", "+x" ...)."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    out = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        area = float(np.prod(hi[others] - lo[others]))
        for sign, value in (("-", lo[axis]), ("+", hi[axis])):
            if f"{sign}{'xyz'[axis]}" in skip:
                continue
            n = max(1, int(round(density * area)))
            pts = rng.uniform(lo, hi, size=(n, 3))
            pts[:, axis] = value
            out.append(pts)
    return np.vstack(out)


@dataclass
class SiblingFingers:
    points_a: np.ndarray  # (n, 3) the links' surface points, configuration A (world)
    labels: np.ndarray  # (n,) 0 palm, 1 and 2 the fingers
    link_motions: list[Similarity]  # per link, A -> B (B's own frame and scale)
    parents: list[int]  # true parent of each link (-1 for the palm)
    hinges: list[np.ndarray]  # true axis point of fingers 1 and 2 (the axes are along z)


def make_sibling_fingers(seed: int = 0, angle_deg: float = 30.0, sibling_gap: float = 0.0008,
                         base_gap: float = 0.001, density: float = 4e5) -> SiblingFingers:
    """Two fingers hinged on a palm, touching each other more than they touch the palm.

    After the Barrett hand (metres): a 12 x 12 x 4 cm palm on the table (its bottom unseen), its
    top at z = 0; on it two fingers
    at y = +-2.5 cm, each a 3 x 3 x 6 cm post standing ``base_gap`` above the palm (the palm
    under the post and the post's bottom are hidden, as under a real knuckle) with an arm to -x
    whose tip bends over to the other finger: the two tips face each other ``sibling_gap`` apart
    over 3 x 3 cm. Each finger turns about the vertical axis through its post by ``angle_deg``,
    mirror images of each other, as the hand's spread. Their motion relative to each other is a
    clean rotation by twice the angle about a vertical axis between the posts, 1 cm from either
    (nearer the fingers than each finger's own axis is to its post's surface, 1.5 cm), but
    6 cm from where the fingers touch. Configuration B has its own frame and scale.
    """
    rng = np.random.default_rng(seed)
    a, half = 0.025, 0.015
    palm = box_surface(rng, [-0.06, -0.06, -0.04], [0.06, 0.06, 0.0], density,
                       skip=("-z",))  # standing on the table
    hidden = np.zeros(len(palm), dtype=bool)
    for y in (a, -a):  # the palm's top under each post
        hidden |= ((palm[:, 2] == 0.0) & (np.abs(palm[:, 0]) < half)
                   & (np.abs(palm[:, 1] - y) < half))
    parts = [palm[~hidden]]
    hinges = []
    for side in (1.0, -1.0):
        y = side * a
        z0 = base_gap
        finger = [
            box_surface(rng, [-half, y - half, z0], [half, y + half, z0 + 0.06], density,
                        skip=("-z",)),  # post
            box_surface(rng, [-0.09, y - 0.008, z0 + 0.03], [-half, y + 0.008, z0 + 0.06],
                        density),  # arm to -x
        ]
        inner = side * sibling_gap / 2  # the tip's face towards the other finger
        lo_y, hi_y = sorted((inner, y - side * 0.008))
        finger.append(box_surface(rng, [-0.09, lo_y, z0 + 0.03], [-0.06, hi_y, z0 + 0.06],
                                  density))  # tip, bent over to the other finger
        parts.append(np.vstack(finger))
        hinges.append(np.array([0.0, y, 0.0]))
    points = np.vstack(parts)
    labels = np.repeat(np.arange(3), [len(q) for q in parts])
    frame_b = Similarity(Rotation.random(random_state=int(rng.integers(2**31))).as_matrix(),
                         rng.uniform(-1, 1, 3), float(np.exp(rng.uniform(-1.0, 1.0))))
    motions = [frame_b]
    for hinge, sign in zip(hinges, (1.0, -1.0), strict=True):
        rot = Rotation.from_rotvec(sign * np.deg2rad(angle_deg) * np.array([0.0, 0.0, 1.0]))
        r = rot.as_matrix()
        motions.append(frame_b @ Similarity(r, hinge - r @ hinge, 1.0))
    return SiblingFingers(points, labels, motions, [-1, 0, 0], hinges)


def match_links(pred: np.ndarray, true: np.ndarray, n_true: int) -> dict[int, int]:
    """Map each predicted link to the true link holding most of its members (majority vote)."""
    mapping = {}
    for k in range(int(pred.max()) + 1 if len(pred) and pred.max() >= 0 else 0):
        t = true[pred == k]
        t = t[t >= 0]
        if len(t):
            mapping[k] = int(np.bincount(t, minlength=n_true).argmax())
    return mapping


def line_distance(p1, d1, p2, d2) -> float:
    """Distance between two 3D lines (point-to-line distance when parallel)."""
    n = np.cross(d1, d2)
    nn = np.linalg.norm(n)
    w = np.asarray(p2) - np.asarray(p1)
    if nn < 1e-9:
        return float(np.linalg.norm(np.cross(w, d1)) / np.linalg.norm(d1))
    return float(abs(w @ n) / nn)


def axis_angle_error(d1, d2) -> float:
    """Angle between two axis directions, ignoring sign (rad)."""
    # atan2 form: arccos loses half the digits near 0 (1e-8 rad for identical unit vectors)
    return float(np.arctan2(np.linalg.norm(np.cross(d1, d2)), abs(float(np.dot(d1, d2)))))


def joint_errors(est, true: TrueJoint, mapping: dict[int, int]) -> dict[str, float]:
    """Axis angle (rad), axis line distance (world units; prismatic: 0, the line is free) and
    state error of an estimated joint against the truth (signs reconciled through the axis).
    `mapping` maps estimated link indices to true ones (see match_links)."""
    sign = 1.0 if float(np.dot(est.axis_direction, true.axis_direction)) >= 0 else -1.0
    if mapping.get(est.parent) == true.child:  # the joint seen from the other link: opposite sign
        sign = -sign
    state_err = abs(sign * est.motion - true.value)
    line = (
        line_distance(est.axis_point, est.axis_direction, true.axis_point, true.axis_direction)
        if true.type == "revolute"
        else 0.0
    )
    return {
        "angle": axis_angle_error(est.axis_direction, true.axis_direction),
        "line": line,
        "state": state_err,
    }


def find_true_joint(est, truth: list[TrueJoint], mapping: dict[int, int]) -> TrueJoint | None:
    """The true joint between the true links of an estimated joint's parent and child."""
    ends = {mapping.get(est.parent), mapping.get(est.child)}
    for t in truth:
        if {t.parent, t.child} == ends:
            return t
    return None


def box_faces(centre, half, step=0.002):
    """Points on the surface of an axis-aligned box, every ``step``, with outward normals: the
    reconstructed surface of a box-shaped part (the plan's tests). : (n, 3), (n, 3)"""
    pts, nrm = [], []
    for ax in range(3):
        u, v = [k for k in range(3) if k != ax]
        gu = np.arange(-half[u], half[u] + 1e-9, step)
        gv = np.arange(-half[v], half[v] + 1e-9, step)
        a, b = (g.ravel() for g in np.meshgrid(gu, gv))
        for sign in (-1.0, 1.0):
            p = np.zeros((a.size, 3))
            p[:, ax], p[:, u], p[:, v] = sign * half[ax], a, b
            n = np.zeros((a.size, 3))
            n[:, ax] = sign
            pts.append(p + centre)
            nrm.append(n)
    return np.vstack(pts), np.vstack(nrm)


def ring_cameras(n_views: int, radius: float, elevations_deg=(50.0,)) -> list[tuple[np.ndarray,
                                                                                     np.ndarray]]:
    """Cameras on rings about the vertical axis looking at the origin, OpenCV convention (z
    forward, x level): ``(R_cw, t_cw)`` per view, ring by ring."""
    out = []
    for el in elevations_deg:
        e = np.radians(el)
        for k in range(n_views):
            az = 2 * np.pi * k / n_views
            centre = radius * np.array([np.cos(az) * np.cos(e), np.sin(az) * np.cos(e), np.sin(e)])
            z = -centre / np.linalg.norm(centre)
            x = np.cross(z, [0.0, 0.0, 1.0])
            x /= np.linalg.norm(x)
            R = np.stack([x, np.cross(z, x), z])
            out.append((R, -R @ centre))
    return out
