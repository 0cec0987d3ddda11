"""Why the matches give no articulated object, said plainly: nothing moved, the whole object
moved as one body, or the two image sets show different objects.

A run whose matches form fewer than two links fails either way; these checks choose the
explanation a user can act on. :func:`check_motion` runs before segmentation (whose own failure
would name other causes); :func:`explain_segmentation_failure` turns a segmentation that left
fewer than two links into the likelier cause. Both are called by
:func:`artrecon.articulation.find_links`. :func:`blame_poses` names given camera poses that agree
poorly with the images as the likely cause of a failure of the links or the joints stage.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artrecon import tolerances as tol
from artrecon.errors import (
    DegenerateError,
    NoMotionError,
    ReconstructionError,
    SingleBodyError,
    WeakEvidenceError,
)
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
#: :func:`check_motion` says "nothing moved" or "moved as one body" only when at least this share
#: of each configuration's SfM points on the object found a partner by descriptor (the matching,
#: before any motion-guided search): the same object seen twice matches many of its points, an
#: other object in its place a few chance pairings (or the table around it), which then fit the
#: room's motion and would pass for "nothing moved". Measured (smaller share of A's and B's, at
#: 9889061 on existing configurations, default settings): bundled scenes scissors 0.29, cabinet
#: 0.46, drawer 0.54, scraper_truck 0.54; the rendered hinge seen twice unmoved (from views half
#: a step apart) 0.66; the hinge against another object in the same room 0.012 (50 of B's 4285
#: points). The threshold sits about midway (in ratio) between them, and only
#: picks the message of a run that is refused either way.
MIN_MATCHED_SHARE = 0.05


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


def different_objects(n: int, object_points: tuple[int, int] | None,
                      verdict: str) -> ReconstructionError | None:
    """The error saying that A and B show different objects when the ``n`` matches on the object
    are fewer than ``MIN_MATCHED_SHARE`` of A's or of B's SfM points on it (``object_points``);
    None when they are not, or without ``object_points``. ``verdict`` is what the matches alone
    would have said, for the message."""
    if object_points is None:
        return None
    n_a, n_b = (int(k) for k in object_points)
    if min(n_a, n_b) == 0:
        return None
    share = n / max(n_a, n_b)
    if share >= MIN_MATCHED_SHARE:
        return None
    return ReconstructionError(
        f"no consistent link between the two image sets: the object in B does not look like "
        f"A's. Only {n} of the object's SfM points found a partner by their descriptors: "
        f"{100 * n / n_a:.1f}% of A's {n_a} and {100 * n / n_b:.1f}% of B's {n_b} (the same object "
        f"photographed twice matches far more of them, 29-71% in four bundled scenes; need "
        f"{100 * MIN_MATCHED_SHARE:.0f}% of each), so those matches are chance pairings or the "
        f"static surroundings, and what they would say ({verdict}) is no evidence about the "
        "object. Are both image sets of the same object, photographed from similar directions? "
        "If they are, photograph it with more texture or sharper images, so that more of its "
        "points match across the two sets.")


def check_motion(points_a, points_b, background_a, background_b, seg_config,
                 seed: int = 0, *, object_points: tuple[int, int] | None = None) -> None:
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

    Both verdicts take A's object for B's. When fewer than ``MIN_MATCHED_SHARE`` of either
    configuration's object points (``object_points``) have a match, the object in B does not look
    like A's: the few matches are chance pairings or the surroundings, which fit the room's motion
    by being static, and the run is refused as two different objects instead.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        The object's matches.
    background_a, background_b : (m, 3) float
        The room's matches.
    seg_config : artrecon.segment.SegmentationConfig
    seed : int
    object_points : (int, int), optional
        How many SfM points on the object A and B offered to the matching (matched or not);
        without them the share of matched points is not checked.

    Raises
    ------
    NoMotionError
        Nothing moved (the same configuration photographed twice).
    SingleBodyError
        The object moved as one rigid body against the room.
    ReconstructionError
        Either verdict, but few of the object's points matched: two different objects.
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
    still = gap <= reach and turn < tol.REVOLUTE_MIN_ANGLE
    unlike = different_objects(n, object_points, "nothing moved" if still
                               else "the whole object moved as one rigid body")
    if unlike is not None:
        raise unlike
    if still:
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


def blame_poses(err: Exception, sfms: dict, config) -> Exception:
    """``err`` (a segmentation or joint-evidence failure) with the given camera poses named as its
    likely cause, when they were given and agree with the images worse than
    ``config.suspect_pose_epipolar_px`` (``config``: the run's artrecon.sfm.SfMConfig; though well
    enough to pass the pose check); else ``err``.

    Slightly wrong poses (encoder noise, a camera mount error) put each configuration's points
    in slightly different wrong places, so the matches across configurations stop moving
    together, and segmentation blames the matches ("chance pairings", "too few inliers").
    """
    figures = {k: s.pose_agreement["epipolar_median_px"] for k, s in sfms.items()
               if s.pose_agreement and s.pose_agreement.get("epipolar_median_px") is not None}
    if not any(v > config.suspect_pose_epipolar_px for v in figures.values()):
        return err
    note = (" Likely cause: the given camera poses. They passed the pose check but agree with the "
            "images only to a median " + ", ".join(f"{v:.2f} px ({k.upper()})"
                                                   for k, v in sorted(figures.items()))
            + " from the epipolar lines they predict (exact poses: ~0.1 px); such poses "
            "(a hand-eye / camera mount calibration error, arm encoder errors) put the points of "
            "the two configurations in differently wrong places, so their matches no longer move "
            "together. Run without the poses (without --use-poses) so SfM recovers the cameras "
            "from the images, or recalibrate the camera mount and the arm.")
    if isinstance(err, WeakEvidenceError):
        return WeakEvidenceError(str(err) + note, err.records)
    try:
        return type(err)(str(err) + note)
    except TypeError:  # an error class with another constructor
        return ReconstructionError(str(err) + note)
