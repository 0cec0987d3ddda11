"""How far to trust each estimated joint, and refusal when the evidence is too weak.

For every joint (parent P, child C) the evidence artrecon has is the 3D-3D matches of the two
links and their A -> B transforms. :func:`assess_joints` turns it into a confidence record per
joint (a JSON-ready dict stored in ``Joint.confidence``):

- ``links``: per link its inlier matches, their share of all matches, the Procrustes residual
  (RMS of ``|T(p_a) - p_b|``, model units) and that residual relative to the link's extent
  (``tolerances.scene_size`` of its points);
- ``motion``: how far the child moved relative to the parent (RMS displacement of the child's
  matches under the relative motion, model units; rotation angle in degrees) and the signal to
  noise ratio ``snr`` = that displacement / the larger of the two links' residuals;
- ``bootstrap``: the estimator re-run on inlier sets resampled with replacement (both links,
  ``n`` times, seeded): the RMS angle between the resampled axes and the estimate
  (``axis_spread_deg``), for a revolute joint the RMS distance of the estimate's axis point to the
  resampled axis lines (``point_spread``, model units, and relative to the child's extent), the
  RMS spread of the joint state, and the share of resamples that give the same joint type. For a
  small rotation the axis (the eigenvector of eigenvalue 1) is ill-conditioned and the resampled
  axes scatter: this is the measure of axis conditioning.
- ``score`` in [0, 1]: the share of resamples whose axis is within ``SCORE_AXIS_DEG`` of the
  estimate (and, revolute, whose axis line passes within ``SCORE_POINT_RELATIVE`` x the child's
  extent of the estimate's axis point) with the same type; 0 when refused;
- ``refused`` and ``reasons``: which gate (below) the joint failed, with the figures.

The bootstrap measures the statistical uncertainty of the estimate given the matches; it cannot see
systematic errors common to all matches (a distorted SfM model, wrong matches that happen to agree).
The motion gate (``MIN_MOTION_SNR``) covers part of that: a motion no larger than the residuals
could itself be such an error.

Elsewhere: the plain explanations of a run whose matches give no second link (nothing moved, one
rigid body, different objects) are :mod:`artrecon.diagnosis`; the agreement of two registrations
at each joint's axis is :mod:`artrecon.register.agreement`.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from artrecon import tolerances as tol
from artrecon.errors import DegenerateError, WeakEvidenceError
from artrecon.geometry import skew
from artrecon.joints import JointConfig, joint_from_motion, relative_motion
from artrecon.procrustes import Similarity, rotation_angle

log = logging.getLogger(__name__)

__all__ = [
    "ConfidenceConfig",
    "assess_joints",
    "joint_confidence",
    "rescale_confidence",
    "MIN_LINK_INLIERS",
    "MIN_MOTION_SNR",
    "MAX_AXIS_SPREAD_DEG",
    "MAX_POINT_SPREAD",
    "MIN_TYPE_AGREEMENT",
]

# --- gates (each with why) ----------------------------------------------------------------------

#: A link needs this many inlier matches. Six numbers (a rigid motion) from n noisy points are good
#: to ~1/sqrt(n) of the noise, but a bootstrap of fewer than ~20 samples cannot estimate its own
#: spread (it underestimates it, and the resamples repeat the same few points). The segmentation
#: keeps links down to 12 matches; the bundled scenes' smallest links have 60-80 (pliers, 18 views
#: per ring) to hundreds.
MIN_LINK_INLIERS = 20
#: The child's matches must move (relative to the parent) by this many times the links' residual
#: RMS. Below it the motion is of the size of the reconstruction's own errors, some of which are
#: systematic (SfM distortion, the two models' different drift) and do not average out over many
#: matches: the "joint" could be those errors. The bundled scenes (30 deg or 100 mm; residuals
#: 0.4-1.2% of a link's extent) have ratios of 64-178; 5 degrees or 1 cm still give about ten.
MIN_MOTION_SNR = 3.0
#: Refuse when the resampled axes scatter by more than this (RMS angle to the estimate, degrees).
#: On synthetic pairs the RMS spread matches the RMS true axis error within 10% (30 seeds each,
#: 1-4 degrees). On captures the error runs to 2.5 x the spread: systematic errors (the two SfM
#: models' drift, triangulation bias on thin parts) move all of a link's matches together, which
#: resampling cannot see. Measured at 9b58f88 over 40 evaluations of the bundled scenes and the
#: pliers robustness sweep (18 views per ring): every answer within the 2-degree gate had a spread
#: of at most 1.12 degrees (gate scenes 0.03-0.77: drawer, truck, cabinet, barrett_hand, pliers,
#: pliers_panda, scraper_truck, scissors; image noise 12 grey levels 1.12 with a 1.38-degree
#: error); the two wrong answers, 10 and 5 degrees of joint motion, 1.37 and 2.15 (errors 3.15 and
#: 2.95 degrees). It was 3.0 while the base was fitted to its own matches alone, whose resampling
#: added its thin roll to every spread (pliers 0.9-1.0, now 0.4-0.7).
MAX_AXIS_SPREAD_DEG = 1.25
#: Refuse a revolute joint when the axis line's position scatters by more than this fraction of the
#: child's extent (RMS). 5% of a 20 cm lid is 1 cm, twice the evaluation's 5 mm gate: a grasp
#: moved about such an axis binds. The bundled scenes scatter by 0.2-0.4%.
MAX_POINT_SPREAD = 0.05
#: Refuse when fewer resamples than this share give the estimate's joint type: the relative
#: rotation is within noise of the revolute/prismatic boundary (tolerances.REVOLUTE_MIN_ANGLE), so
#: the type itself is a coin toss.
MIN_TYPE_AGREEMENT = 0.9
#: Resamples of the bootstrap. 200 estimate an RMS spread to about +-5% (the spread of a chi
#: statistic with 200 samples), at a cost of milliseconds per joint.
BOOTSTRAP_SAMPLES = 200
#: Links are resampled from at most this many of their matches (a random subset): the spread is then
#: slightly overestimated for larger links (conservative) while memory stays bounded.
BOOTSTRAP_MAX_POINTS = 20000
#: Resampled points fitted at once (samples x points), bounding memory to ~100 MB of temporaries.
BOOTSTRAP_CHUNK = 1_000_000
#: The score counts resamples whose axis is within this angle (deg) of the estimate ...
SCORE_AXIS_DEG = 2.0
#: ... and (revolute) whose axis line passes within this fraction of the child's extent of the
#: estimate's axis point (the evaluation's 5 mm on objects of 20-30 cm).
SCORE_POINT_RELATIVE = 0.02

#: Keys of a confidence record holding lengths in the model's units (scaled by registration).
_LENGTH_KEYS = {("links", "rms"), ("links", "extent"), ("motion", "displacement"),
                ("motion", "noise"), ("bootstrap", "point_spread"), ("bootstrap", "state_spread")}


@dataclass(frozen=True)
class ConfidenceConfig:
    """Gates and bootstrap settings (defaults: the module constants)."""

    min_link_inliers: int = MIN_LINK_INLIERS
    min_motion_snr: float = MIN_MOTION_SNR
    max_axis_spread_deg: float = MAX_AXIS_SPREAD_DEG
    max_point_spread: float = MAX_POINT_SPREAD
    min_type_agreement: float = MIN_TYPE_AGREEMENT
    bootstrap_samples: int = BOOTSTRAP_SAMPLES
    refuse: bool = True
    """Raise WeakEvidenceError for refused joints. False only marks them (``confidence["refused"]``)
    and returns the model: a diagnostic mode; the exports and sim.manipulate do not check the mark,
    so do not hand such a model to them."""


# --- batched rigid fits --------------------------------------------------------------------------


def _batch_rigid(pa: np.ndarray, pb: np.ndarray, scale: float,
                 w: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (B, 3, 3) and translations (B, 3) of pb ~ scale R pa + t for B point sets
    (weighted least squares with weights ``w`` (B, n) when given)."""
    if w is None:
        w = np.ones(pa.shape[:2])
    w = w / w.sum(axis=1, keepdims=True)
    ma, mb = np.einsum("bn,bni->bi", w, pa), np.einsum("bn,bni->bi", w, pb)
    cov = np.einsum("bni,bnj->bij", (pb - mb[:, None]) * w[:, :, None], pa - ma[:, None])
    u, _, vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= d[:, None]
    R = u @ vt
    t = mb - scale * np.einsum("bij,bj->bi", R, ma)
    return R, t


def _batch_gls_step(pa: np.ndarray, pb: np.ndarray, transform: Similarity, mats: np.ndarray,
                    draw: np.ndarray, prior: tuple | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (B, 3, 3) and translations (B, 3) of the generalised least-squares fit
    (:func:`artrecon.uncertainty.robust_gls_transforms`, its weight matrices ``mats`` (n, 3, 3)
    held, the scale too) of B resamples ``draw`` (B, m) of the n pairs: one Gauss-Newton step
    from ``transform``, the fit of all of them (a linearised bootstrap; the fit is linear in the
    motion to well under a hundredth of a degree at the rotations resampling gives).
    ``prior``: (information (6, 6), gradient (6,)), a fixed term added to every resample's
    normal equations (the link's dense surface, :func:`_surface_priors`)."""
    rot, t, s = transform.rotation, transform.translation, transform.scale
    x = s * pa @ rot.T
    r = x + t - pb
    jac = np.zeros((len(pa), 3, 6))
    jac[:, :, :3] = -skew(x)  # d r / d omega
    jac[:, :, 3:] = np.eye(3)
    jw = np.einsum("nki,nkl->nil", jac, mats)
    h = np.einsum("nil,nlj->nij", jw, jac).reshape(len(pa), 36)
    g = np.einsum("nil,nl->ni", jw, r)
    counts = np.zeros((len(draw), len(pa)))
    np.add.at(counts, (np.repeat(np.arange(len(draw)), draw.shape[1]), draw.ravel()), 1.0)
    hs, gs = (counts @ h).reshape(-1, 6, 6), counts @ g
    if prior is not None:
        hs, gs = hs + prior[0], gs + prior[1]
    step = -np.linalg.solve(hs, gs[:, :, None])[:, :, 0]
    rots = Rotation.from_rotvec(step[:, :3]).as_matrix() @ rot
    return rots, t + step[:, 3:]


def _line_distance(p, q, v) -> float:
    """Distance of point p to the line (q, v) -- v unit."""
    w = np.asarray(p) - np.asarray(q)
    return float(np.linalg.norm(w - (w @ v) * v))


# --- one joint -----------------------------------------------------------------------------------


def _link_evidence(k, pa, pb, transform: Similarity, n_all: int) -> dict:
    s = transform.scale
    res = np.linalg.norm(transform.apply(pa) - pb, axis=1) / s  # model units (configuration A)
    extent = tol.scene_size(pa) if len(pa) else 0.0
    rms = float(np.sqrt(np.mean(res ** 2))) if len(res) else float("nan")
    return {"link": int(k), "inliers": int(len(pa)), "share": float(len(pa) / max(n_all, 1)),
            "rms": rms, "extent": float(extent),
            "rms_relative": float(rms / extent) if extent > 0 else float("inf")}


def joint_confidence(joint, points_a, points_b, segmentation, joint_config=None,
                     config: ConfidenceConfig = ConfidenceConfig(),  # noqa: B008 (frozen)
                     seed: int = 0, anchors: dict | None = None) -> dict:
    """Confidence record of one joint (see the module docstring); does not raise on weak evidence.

    Parameters
    ----------
    joint : artrecon.model.Joint
        From :func:`artrecon.joints.estimate_joints` on the same matches and segmentation.
    points_a, points_b : (n, 3) float
        The matches given to segment_links.
    segmentation : Segmentation
    joint_config : artrecon.joints.JointConfig, optional
        The settings the joint was estimated with (its revolute/prismatic boundary).
    config : ConfidenceConfig
    seed : int
    anchors : dict, optional
        ``{link: (points_a, points_b[, weights])}``, further matches the link's transform was
        fitted to (see :func:`assess_joints`); resampled with its own in the bootstrap.

    Returns
    -------
    dict
        JSON-ready; lengths in model units.
    """
    joint_config = joint_config or JointConfig()
    pa_all = np.asarray(points_a, dtype=float)
    pb_all = np.asarray(points_b, dtype=float)
    labels = np.asarray(segmentation.labels)
    n_all = len(labels)
    P, C = joint.parent, joint.child
    idx = {k: np.flatnonzero(labels == k) for k in (P, C)}
    T = segmentation.transforms
    links = {k: _link_evidence(k, pa_all[idx[k]], pb_all[idx[k]], T[k], n_all) for k in (P, C)}
    rec: dict = {"joint": joint.name, "type": joint.type, "parent": links[P], "child": links[C],
                 "length_unit": "model units"}

    # Motion against noise.
    child_a = pa_all[idx[C]]
    rel = relative_motion(T[P], T[C])
    disp = np.linalg.norm(rel.apply(child_a) - child_a, axis=1) if len(child_a) else np.zeros(1)
    disp_rms = float(np.sqrt(np.mean(disp ** 2)))
    noise = max(links[P]["rms"], links[C]["rms"])
    snr = disp_rms / noise if noise > 0 else float("inf")
    rec["motion"] = {"displacement": disp_rms,
                     "displacement_relative": disp_rms / links[C]["extent"]
                     if links[C]["extent"] > 0 else float("inf"),
                     "rotation_deg": float(np.degrees(rotation_angle(rel.rotation))),
                     "noise": noise, "snr": float(snr)}

    # Bootstrap of the estimator over the two links' inliers (and the matches anchoring them),
    # each match with the weight the links' fit gave it (segmentation.weights, robust refit).
    # With the matches' weight matrices (the fit knew their triangulation covariances,
    # segmentation.precisions), the resampled fits weigh each match's directions as that fit did.
    boot_idx = dict(idx)
    w_all = (np.ones(n_all) if segmentation.weights is None
             else np.asarray(segmentation.weights, float))
    m_all = segmentation.precisions
    for k, anchor in (anchors or {}).items():
        xa, xb = anchor[:2]
        if k in boot_idx and len(xa):
            boot_idx[k] = np.concatenate([idx[k], len(pa_all) + np.arange(len(xa))])
            pa_all, pb_all = np.vstack([pa_all, xa]), np.vstack([pb_all, xb])
            w_all = np.r_[w_all, anchor[2] if len(anchor) > 2 else np.ones(len(xa))]
            m_all = np.concatenate([m_all, anchor[3]]) \
                if m_all is not None and len(anchor) > 3 else None
    rec["bootstrap"] = _bootstrap(joint, pa_all, pb_all, idx, T, segmentation.scale,
                                  links[C]["extent"], joint_config, config.bootstrap_samples,
                                  seed, joint_from_motion, relative_motion, fit_idx=boot_idx,
                                  weights=w_all, matrices=m_all,
                                  surface=_surface_priors(segmentation))

    reasons = []
    for k, role in ((P, "parent"), (C, "child")):
        if links[k]["inliers"] < config.min_link_inliers:
            reasons.append(f"the {role} link {k} has only {links[k]['inliers']} inlier matches "
                           f"(need {config.min_link_inliers})")
    if not snr >= config.min_motion_snr:
        unit = "deg" if joint.type == "revolute" else "model units"
        amount = np.degrees(joint.motion) if joint.type == "revolute" else joint.motion
        reasons.append(f"the motion ({amount:.4g} {unit}, relative rotation "
                       f"{rec['motion']['rotation_deg']:.3g} deg; the child's matches moved by "
                       f"{disp_rms:.3g} model units RMS) is only {snr:.2f} x the residual noise "
                       f"{noise:.3g} (need {config.min_motion_snr:g} x)")
    b = rec["bootstrap"]
    if b["type_agreement"] < config.min_type_agreement:
        reasons.append(f"the joint type is undetermined: only {100 * b['type_agreement']:.0f}% of "
                       f"the resampled estimates are {joint.type} (need "
                       f"{100 * config.min_type_agreement:.0f}%)")
    if not b["axis_spread_deg"] <= config.max_axis_spread_deg:
        reasons.append(f"the axis direction is ill-determined: resampling the matches moves it by "
                       f"{b['axis_spread_deg']:.2f} deg RMS (limit {config.max_axis_spread_deg:g}"
                       " deg)")
    if joint.type == "revolute" and not b["point_spread_relative"] <= config.max_point_spread:
        reasons.append(f"the axis position is ill-determined: resampling moves it by "
                       f"{100 * b['point_spread_relative']:.1f}% of the child's extent RMS (limit "
                       f"{100 * config.max_point_spread:g}%)")
    rec["refused"] = bool(reasons)
    rec["reasons"] = reasons
    rec["score"] = 0.0 if reasons else b["within_tolerance"]
    return rec


def _surface_priors(segmentation) -> dict:
    """``{link: (information (6, 6), gradient (6,))}``: what each link's dense surface says of
    its motion (:func:`artrecon.surface_fit.surface_refit`), for the links it refined."""
    info, grad = segmentation.surface_information, segmentation.surface_gradient
    if info is None or grad is None:
        return {}
    return {k: (info[k], grad[k]) for k in range(len(info)) if np.any(info[k])}


def _bootstrap(joint, pa_all, pb_all, idx, T, scale, child_extent, joint_config, n_boot, seed,
               joint_from_motion, relative_motion, fit_idx=None, weights=None,
               matrices=None, surface=None) -> dict:
    """Resample each link's fit (over ``fit_idx``, default ``idx``: its members, and any matches
    anchoring it; each match with its ``weights`` entry, default 1, or its weight matrix
    ``matrices`` (:func:`_batch_gls_step`) when given) and re-estimate the joint (with the
    links' own points, ``idx``). ``surface``: ``{link: (information, gradient)}``, the dense
    surface's term of a link's fit (:func:`_surface_priors`), held in each resample: the matches
    are resampled, the surface the link was refitted with stays."""
    rng = np.random.default_rng(seed)
    P, C = joint.parent, joint.child
    fit_idx = idx if fit_idx is None else fit_idx
    fits = {}
    for k in (P, C):
        members = fit_idx[k]
        if len(members) > BOOTSTRAP_MAX_POINTS:
            members = rng.choice(members, BOOTSTRAP_MAX_POINTS, replace=False)
        if len(members) < 3:
            fits[k] = None
            continue
        draw = rng.integers(0, len(members), size=(n_boot, len(members)))
        chunk = max(1, BOOTSTRAP_CHUNK // len(members))  # bounds memory: chunk x n x 3 floats
        if matrices is not None:
            prior = (surface or {}).get(k)
            parts = [_batch_gls_step(pa_all[members], pb_all[members], T[k], matrices[members], d,
                                     prior)
                     for d in np.array_split(draw, range(chunk, n_boot, chunk))]
        else:
            parts = [_batch_rigid(pa_all[members[d]], pb_all[members[d]], scale,
                                  None if weights is None else weights[members[d]])
                     for d in np.array_split(draw, range(chunk, n_boot, chunk))]
        fits[k] = (np.concatenate([r for r, _ in parts]), np.concatenate([t for _, t in parts]))
    out = {"samples": int(n_boot), "axis_spread_deg": float("inf"), "point_spread": float("inf"),
           "point_spread_relative": float("inf"), "state_spread": float("inf"),
           "type_agreement": 0.0, "within_tolerance": 0.0}
    if fits[P] is None or fits[C] is None:
        return out
    pts_p, pts_c = pa_all[idx[P]], pa_all[idx[C]]
    angles, dists, states, same = [], [], [], []
    for b in range(n_boot):
        tp = Similarity(fits[P][0][b], fits[P][1][b], scale)
        tc = Similarity(fits[C][0][b], fits[C][1][b], scale)
        try:
            jb = joint_from_motion(relative_motion(tp, tc), P, C, pts_p, pts_c, joint_config)
        except DegenerateError:
            same.append(False)
            continue
        same.append(jb.type == joint.type)
        if jb.type != joint.type:
            continue
        cosang = float(np.clip(jb.axis_direction @ joint.axis_direction, -1.0, 1.0))
        angles.append(np.degrees(np.arctan2(
            np.linalg.norm(np.cross(jb.axis_direction, joint.axis_direction)), cosang)))
        states.append(jb.motion - joint.motion)
        if joint.type == "revolute":
            dists.append(_line_distance(joint.axis_point, jb.axis_point, jb.axis_direction))
    out["type_agreement"] = float(np.mean(same))
    if not angles:
        return out
    angles = np.array(angles)
    out["axis_spread_deg"] = float(np.sqrt(np.mean(angles ** 2)))
    out["axis_spread_p95_deg"] = float(np.percentile(angles, 95))
    out["state_spread"] = float(np.sqrt(np.mean(np.square(states))))
    if joint.type == "revolute":
        out["state_spread_deg"] = float(np.degrees(out.pop("state_spread")))  # an angle
        d = np.array(dists)
        out["point_spread"] = float(np.sqrt(np.mean(d ** 2)))
        out["point_spread_relative"] = out["point_spread"] / child_extent \
            if child_extent > 0 else float("inf")
        ok = (angles <= SCORE_AXIS_DEG) & (d <= SCORE_POINT_RELATIVE * child_extent)
    else:
        out["point_spread"] = out["point_spread_relative"] = 0.0  # the line's position is free
        ok = angles <= SCORE_AXIS_DEG
    out["within_tolerance"] = float(ok.sum() / n_boot)
    return out


# --- all joints -----------------------------------------------------------------------------------


def assess_joints(points_a, points_b, segmentation, joints, joint_config=None,
                  config: ConfidenceConfig = ConfidenceConfig(),  # noqa: B008 (frozen)
                  seed: int = 0, anchors: dict | None = None) -> dict:
    """Attach a confidence record to every joint (``joint.confidence``); refuse weak ones.

    Parameters
    ----------
    points_a, points_b : (n, 3) float
        The matches given to segment_links.
    segmentation : Segmentation
    joints : list of Joint
        From estimate_joints (modified in place: ``confidence`` is set).
    joint_config : JointConfig, optional
    config : ConfidenceConfig
    seed : int
    anchors : dict, optional
        ``{link: (points_a, points_b[, weights])}``: matches outside the segmentation that the
        link's transform was also fitted to (the background, for the base:
        :func:`artrecon.link_motions.anchor_to_background`); the bootstrap resamples them with
        the link's own.

    Returns
    -------
    dict
        Summary for the model's metadata: the gates and, per joint, score and refusal.

    Raises
    ------
    WeakEvidenceError
        When ``config.refuse`` and some joint fails a gate; the message names each such joint and
        the figure, ``.records`` holds every joint's record.
    """
    records = []
    for j in joints:
        rec = joint_confidence(j, points_a, points_b, segmentation, joint_config, config, seed,
                               anchors)
        j.confidence = rec
        records.append(rec)
        b, m = rec["bootstrap"], rec["motion"]
        log.info("joint %s confidence %.2f: inliers %d/%d, residual %.2f%%/%.2f%% of extent, "
                 "motion snr %.1f, axis spread %.3f deg, point spread %.2f%%%s", j.name,
                 rec["score"], rec["parent"]["inliers"], rec["child"]["inliers"],
                 100 * rec["parent"]["rms_relative"], 100 * rec["child"]["rms_relative"],
                 m["snr"], b["axis_spread_deg"], 100 * b["point_spread_relative"],
                 " REFUSED: " + "; ".join(rec["reasons"]) if rec["refused"] else "")
    summary = {"gates": {k: v for k, v in asdict(config).items()
                         if k not in ("refuse", "bootstrap_samples")},
               "bootstrap_samples": config.bootstrap_samples,
               "joints": {r["joint"]: {"score": r["score"], "refused": r["refused"]}
                          for r in records}}
    refused = [r for r in records if r["refused"]]
    if refused and config.refuse:
        lines = [f"joint {r['joint']} (links {r['parent']['link']} -> {r['child']['link']}, "
                 f"{r['type']}): " + "; ".join(r["reasons"]) for r in refused]
        raise WeakEvidenceError(
            "the evidence is too weak to give a joint axis: " + " | ".join(lines) + ". Move the "
            "joint further between the two captures (tens of degrees or centimetres), photograph "
            "the moving part from more views, or add texture to it.", records)
    return summary


def rescale_confidence(record: dict, scale: float, unit: str = "m") -> dict:
    """A copy of a confidence record with its lengths multiplied by ``scale`` and labelled
    ``unit`` (e.g. metres per model unit when the model is registered). Relative figures, counts
    and angles stay."""
    if not record:
        return record
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in record.items()}
    for section, key in _LENGTH_KEYS:
        for name in ((section,) if section != "links" else ("parent", "child")):
            if name in out and isinstance(out[name].get(key), (int, float)):
                out[name][key] = out[name][key] * scale
    out["length_unit"] = unit
    return out
