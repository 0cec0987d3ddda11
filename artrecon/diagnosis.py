"""Why the matches give no articulated object, said plainly: nothing moved, the whole object
moved as one body, or the two image sets show different objects.

A run whose matches form fewer than two links fails either way; these checks choose the
explanation a user can act on. :func:`check_motion` runs before segmentation (whose own failure
would name other causes); :func:`explain_segmentation_failure` turns a segmentation that left
fewer than two links into the likelier cause. Both are called by
:func:`artrecon.articulation.articulate`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artrecon import tolerances as tol
from artrecon.errors import DegenerateError, NoMotionError, ReconstructionError, SingleBodyError
from artrecon.geometry import rotation_angle
from artrecon.segment import min_link_size, segment_links

#: When segmentation leaves fewer than two links, and fewer than this share of the object's matches
#: agree on any one rigid motion, the matches are mostly chance pairings: the two image sets show
#: different objects (or the matching failed), not one object that moved rigidly. Real captures
#: put 83-91% of their matches in links (bundled scenes); a rendered other object in the same room
#: gave 11% and 45% (the static floor near the object matches). Either way the run is refused;
#: this only picks the explanation the message leads with (it keeps the segmentation's own).
MIN_CONSISTENT_SHARE = 0.7
#: Fewest background (room) matches that show the room's motion between A and B for
#: :func:`check_motion` (as many as artrecon.link_motions needs to find the base).
MIN_ROOM_MATCHES = 20
#: :func:`check_motion` peels off at most this many groups of left-over matches that move like
#: the object's main motion (each refit is one single-link segmentation).
MAX_ALIKE_GROUPS = 4
#: Two fits move a group of matches alike when they put it less than this many times the larger
#: of their inlier distances apart (or 0.1% of the object's size): within the noise of the fits.
ALIKE_THRESHOLDS = 3.0


def explain_segmentation_failure(exc: Exception, points_a, points_b, seg_config,
                                 seed: int = 0) -> Exception:
    """The error to raise when segmentation left fewer than two links (segment_links, or after
    merging links that move alike, build_kinematic_tree).

    ``exc`` (SingleBodyError, DegenerateError) says the object moved as one body or the matches
    are bad; when fewer than ``MIN_CONSISTENT_SHARE`` of the matches move together under any rigid
    motion, the likelier cause is two image sets of different objects: a ReconstructionError
    saying so, with the figure. Otherwise ``exc`` itself.
    """
    if isinstance(exc, NoMotionError):
        return exc
    n = len(points_a)
    try:
        seg = segment_links(points_a, points_b, replace(seg_config, min_links=1), seed=seed)
        share = float(seg.sizes.max() / n) if seg.n_links else 0.0
    except DegenerateError:
        share = 0.0
    if share >= MIN_CONSISTENT_SHARE:
        return exc
    return ReconstructionError(
        f"no consistent link between the two image sets: at most {100 * share:.0f}% of the {n} "
        f"matches on the object move together under one rigid motion (a real object: most of "
        f"them; need {100 * MIN_CONSISTENT_SHARE:.0f}%), so the matches are chance pairings. Are "
        "both image sets of the same object, photographed from similar directions? If they "
        "are, the two sets' models disagree beyond the matches' noise: take more views per ring "
        "(the drawer failed so at 12 per ring, and with 2.5 px of blur) or sharper images "
        f"(segmentation: {exc})")


def check_motion(points_a, points_b, background_a, background_b, seg_config,
                 seed: int = 0) -> None:
    """Say first and plainly when nothing moved between A and B, or when the whole object moved
    as one rigid body: before segmentation, whose failure would name other causes.

    The object's matches are fitted by one similarity (the largest link segmentation would find
    alone). When the matches it leaves hold no rigid group of a link's size (``min_link_size``;
    wrong matches move every which way), no second link can be found: the object moved as one
    body, if at all. The room does not move; its matches
    (``background_a``, ``background_b``) give the similarity of A's frame to B's. When the two
    similarities move the object's points alike (within the segmentation's inlier distance and
    under ``tolerances.REVOLUTE_MIN_ANGLE``) nothing moved; otherwise the object moved against the
    room as one body. Without enough room matches nothing is concluded here.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        The object's matches.
    background_a, background_b : (m, 3) float
        The room's matches.
    seg_config : artrecon.segment.SegmentationConfig
    seed : int

    Raises
    ------
    NoMotionError
        Nothing moved (the same configuration photographed twice).
    SingleBodyError
        The object moved as one rigid body against the room.
    """
    n = len(points_a)
    if n < 3 or len(background_a) < MIN_ROOM_MATCHES:
        return
    one = replace(seg_config, min_links=1, max_links=1)
    try:
        obj = segment_links(points_a, points_b, one, seed=seed)
        room = segment_links(background_a, background_b, one, seed=seed)
    except DegenerateError:
        return
    if obj.n_links == 0 or room.n_links == 0:
        return
    least = min_link_size(seg_config, n)
    T_obj, T_room = obj.transforms[0], room.transforms[0]
    # The matches left over: a rigid group of a link's size that moves otherwise is a part that
    # moved (segmentation decides); groups that move like the first are the same body (its
    # matches a little beyond the first fit's tight inlier distance: noise-free renders left
    # 452 of 2089 so, 436 of them moving alike); what is left then is wrong matches.
    rest = np.flatnonzero(np.asarray(obj.labels) < 0)
    for _ in range(MAX_ALIKE_GROUPS):
        if len(rest) < least:
            break
        try:
            group = segment_links(points_a[rest], points_b[rest], one, seed=seed)
        except DegenerateError:
            break
        if group.n_links == 0 or group.sizes[0] < least:
            break
        members = rest[np.asarray(group.labels) == 0]
        apart = float(np.median(np.linalg.norm(T_obj.apply(points_a[members])
                                               - group.transforms[0].apply(points_a[members]),
                                               axis=1)))
        alike = max(ALIKE_THRESHOLDS * max(obj.thresholds[0], group.thresholds[0]),
                    tol.NO_MOTION_DISPLACEMENT * obj.scene_size_b)
        if apart > alike or rotation_angle(T_obj.rotation.T @ group.transforms[0].rotation) \
                >= tol.REVOLUTE_MIN_ANGLE:
            return  # a part moved otherwise: segmentation decides
        rest = np.setdiff1d(rest, members)
    left = len(rest)
    gap = float(np.median(np.linalg.norm(T_room.apply(points_a) - T_obj.apply(points_a),
                                         axis=1)))
    turn = rotation_angle(T_obj.rotation.T @ T_room.rotation)
    reach = seg_config.inlier_threshold * obj.scene_size_b
    fits = (f"{n - left} of the {n} matches on the object fit one rigid motion and the other "
            f"{left} no common one (a moving part needs at least {least} matches that move "
            "together otherwise)")
    if gap <= reach and turn < tol.REVOLUTE_MIN_ANGLE:
        raise NoMotionError(
            f"nothing moved between A and B: {fits}, and it is the motion of the room "
            f"({room.sizes[0]} background matches; the two differ by {np.degrees(turn):.2f} deg "
            f"and {100 * gap / obj.scene_size_b:.2f}% of the object's size at the object). The "
            "two image sets show the object in the same configuration. Photograph configuration "
            "B after moving a joint of the object (open the lid, pull the drawer), and pass "
            "that folder as B. (If a part did move, it has too few matches to show it: "
            "photograph it from more views.)")
    raise SingleBodyError(
        f"the whole object moved as one rigid body between A and B, and no joint moved: {fits}, "
        f"and that motion differs from the room's by {np.degrees(turn):.1f} deg and "
        f"{100 * gap / obj.scene_size_b:.1f}% of the object's size. Move a joint of the object "
        "(not the whole object) between the two image sets; if a part did move, photograph it "
        "from more views so that it gets matches of its own")
