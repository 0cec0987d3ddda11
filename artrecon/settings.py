"""The reconstruction's tunable settings: one checked range per field.

:class:`ReconstructConfig` holds every stage's config. A user changes a field of one
with ``artrecon reconstruct ... --set STAGE.FIELD=VALUE`` or a scene's
``<numeric name="reconstruct:STAGE.FIELD" data="VALUE"/>``; :func:`apply_settings` checks
each value against :data:`RANGES` before any work, so that a value no stage can run with
(``nan``, ``inf``, ``dense.downsample=1000``, ``segmentation.max_hypotheses=0``) is refused at
once, naming the field's valid range, instead of failing a minute later with a message about the
images. Every tunable field has a row (a test checks it); a field without one cannot be set. A
tuple field's row (:class:`ListOf`) takes comma-separated values and bounds each.

The ranges bound what the code can run with and what means something; they are not advice:
the defaults (each field's docstring says why) are what the method is measured with.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

import numpy as np

from artrecon.assign import AssignConfig
from artrecon.confidence import ConfidenceConfig
from artrecon.dense import DenseConfig, RegionConfig
from artrecon.errors import InputError
from artrecon.features import GuidedConfig, MatchConfig
from artrecon.freespace import FreeSpaceConfig
from artrecon.joints import JointConfig
from artrecon.match_refine import PhotometricConfig
from artrecon.refine import RefineConfig
from artrecon.segment import SegmentationConfig
from artrecon.sfm import SfMConfig
from artrecon.surface_fit import SurfaceConfig

__all__ = ["Range", "Choice", "ListOf", "RANGES", "ORDERED", "parse_settings", "check_setting",
           "apply_settings", "ReconstructConfig", "with_settings", "jsonable"]


@dataclass(frozen=True)
class Range:
    """The valid values of a numeric (int or float) or boolean setting."""

    low: float
    """Smallest valid value ..."""
    high: float
    """... largest valid value."""
    why: str = ""
    """What the bounds stand for (shown with the range)."""
    low_open: bool = False
    """The value must be strictly greater than ``low``."""
    high_open: bool = False
    """The value must be strictly less than ``high``."""
    odd: bool = False
    """Only odd whole numbers (block sizes)."""

    def text(self) -> str:
        lo = "(" if self.low_open else "["
        hi = ")" if self.high_open else "]"
        odd = ", odd" if self.odd else ""
        why = f" ({self.why})" if self.why else ""
        return f"a value in {lo}{_num(self.low)}, {_num(self.high)}{hi}{odd}{why}"

    def holds(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below and (not self.odd or int(value) % 2 == 1)


@dataclass(frozen=True)
class Choice:
    """The valid values of a text setting."""

    options: tuple[str, ...]

    def text(self) -> str:
        return "one of " + ", ".join(repr(o) for o in self.options)


@dataclass(frozen=True)
class ListOf:
    """The valid values of a list setting (a tuple field): each value within :attr:`item`,
    given as comma-separated values (``--set views.elevations_deg=20,40,60``)."""

    item: Range
    """The range of each value."""
    length: int | None = None
    """How many values the field takes (None: one or more)."""
    may_be_empty: bool = False
    """The field may hold no value, given as ``none`` (``--set views.top_elevations_deg=none``)."""

    def text(self) -> str:
        count = "one or more values" if self.length is None else f"{self.length} values"
        empty = " (or none)" if self.may_be_empty else ""
        return f"{count} separated by commas, each {self.item.text()}{empty}"


def _num(x) -> str:
    """A number as a user would write it: whole numbers without a decimal point."""
    if isinstance(x, str):
        return repr(x)
    x = float(x)
    if math.isfinite(x) and x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return f"{x:g}"


_FRACTION = "a fraction"
_OPEN = dict(low_open=True)

#: One row per tunable field, ``"stage.field"`` as in ReconstructConfig. Lengths given as
#: fractions are of the scene size or camera distance (see each config's docstrings).
RANGES: dict[str, Range | Choice] = {
    # --- sfm (artrecon.sfm.SfMConfig)
    "sfm.max_num_features": Range(100, 65536, "SIFT features per image"),
    "sfm.max_image_size": Range(160, 16384, "pixels, the longer side"),
    "sfm.extractor": Choice(("colmap", "opencv")),
    "sfm.opencv_contrast": Range(0, 0.5, "OpenCV SIFT contrast threshold", **_OPEN),
    "sfm.first_octave": Range(-1, 3, "-1 upsamples the image 2x first"),
    "sfm.region_margin_px": Range(-1, 100_000, "pixels; negative: the whole images"),
    "sfm.background_features": Range(0, 100_000, "features per image; 0: none"),
    "sfm.background_scale": Range(0, 1, "a fraction of the image size", **_OPEN),
    "sfm.matching": Choice(("auto", "exhaustive", "sequential")),
    "sfm.pose_neighbours": Range(1, 1000, "images matched with each image"),
    "sfm.pose_ba_refinements": Range(0, 100, "rounds of points-only bundle adjustment"),
    "sfm.pose_verify_min_trials": Range(1, 100_000, "RANSAC trials, at least"),
    "sfm.pose_max_angle_deg": Range(0, 180, "degrees", **_OPEN),
    "sfm.sequential_window": Range(1, 1000, "neighbours in name order"),
    "sfm.retrieval_neighbours": Range(0, 1000, "0: no retrieval pairs"),
    "sfm.retrieval_sample": Range(10, 100_000, "descriptors per image"),
    "sfm.global_ba_growth": Range(1, 100, "a factor of growth", **_OPEN),
    "sfm.min_registered_fraction": Range(0, 1, _FRACTION, **_OPEN),
    "sfm.num_threads": Range(-1, 1024, "-1 or 0: all cores"),
    "sfm.max_layout_error": Range(0, 1, "a fraction of the cameras' spread", **_OPEN),
    "sfm.max_focal_mismatch": Range(0, 100, _FRACTION, **_OPEN),
    "sfm.min_focal_reprojection_gain": Range(1, 1000, "a factor"),
    "sfm.max_pose_epipolar_px": Range(0, 1000, "pixels", **_OPEN),
    "sfm.min_pose_triangulated_share": Range(0, 1, _FRACTION),
    "sfm.suspect_pose_epipolar_px": Range(0, 1000, "pixels", **_OPEN),
    # --- dense (artrecon.dense.DenseConfig)
    "dense.downsample": Range(1, 8, "1 full resolution; at 8 a 640x480 image is 80x60 "
                              "pixels, about the least block matching can work on"),
    "dense.min_pair_angle_deg": Range(0, 90, "degrees", **_OPEN),
    "dense.max_pair_angle_deg": Range(0, 90, "degrees", **_OPEN),
    "dense.block_size": Range(1, 31, "SGBM block, pixels", odd=True),
    "dense.uniqueness_ratio": Range(0, 100, "percent"),
    "dense.disparity_margin": Range(0, 512, "pixels"),
    "dense.edge_erosion_px": Range(0, 64, "pixels, 0 keeps the edges"),
    "dense.edge_jump_px": Range(0, 100, "pixels of disparity", **_OPEN),
    "dense.depth_tolerance": Range(0, 0.5, "a fraction of the depth", **_OPEN),
    "dense.min_consistent": Range(1, 1000, "other images"),
    "dense.max_free_space_ratio": Range(0, 1, _FRACTION),
    "dense.crop_radius": Range(0, 100, "a fraction of the camera distance", **_OPEN),
    "dense.voxel_pixels": Range(0, 100, "pixels", **_OPEN),
    "dense.normal_neighbours": Range(3, 1000, "points"),
    "dense.pair_cover": Range(0, 1, "0 every image a reference, 1 a cover of the pairs"),
    # --- region (artrecon.dense.RegionConfig)
    "region.radius_fraction": Range(0, 100, "a fraction of the camera distance", **_OPEN),
    "region.plane_tolerance": Range(0, 1, "a fraction of the camera distance", **_OPEN),
    "region.plane_min_fraction": Range(0, 1, _FRACTION),
    "region.plane_iterations": Range(1, 1_000_000, "RANSAC hypotheses"),
    "region.plane_noise_factor": Range(0, 1000, "times the table's noise", **_OPEN),
    "region.plane_min_height": Range(0, 1, "a fraction of the camera distance"),
    # --- match (artrecon.features.MatchConfig, GuidedConfig)
    "match.ratio": Range(0, 1, "Lowe's ratio", **_OPEN),
    "match.images_per_image": Range(1, 10_000, "images"),
    "match.retrieval_sample": Range(10, 100_000, "descriptors per image"),
    "match.min_votes": Range(1, 1000, "image pairs"),
    "match.min_matches": Range(3, 10_000_000, "3D-3D matches"),
    "guided.enabled": Range(0, 1, "0 or 1"),
    "guided.min_similarity": Range(0, 1, "cosine similarity"),
    "guided.margin": Range(0, 1, "cosine similarity"),
    "guided.rounds": Range(0, 100, "0: no guided matching"),
    # --- segmentation (artrecon.segment.SegmentationConfig)
    "segmentation.inlier_threshold": Range(0, 1, "a fraction of the scene size", **_OPEN),
    "segmentation.adaptive_threshold_factor": Range(0, 1000, "times the median residual",
                                                    **_OPEN),
    "segmentation.min_link_points": Range(3, 10_000_000, "matches (3 fix a rigid motion)"),
    "segmentation.min_link_fraction": Range(0, 0.5, _FRACTION),
    "segmentation.confidence": Range(0, 1, "a probability", low_open=True, high_open=True),
    "segmentation.max_hypotheses": Range(1, 10_000_000, "hypotheses per round"),
    "segmentation.min_hypotheses": Range(1, 10_000_000, "hypotheses per round"),
    "segmentation.min_triplet_spread": Range(0, 1, "a fraction of the scene size",
                                             high_open=True),
    "segmentation.score_subset": Range(16, 100_000_000, "matches"),
    "segmentation.batch_size": Range(1, 1_000_000, "hypotheses"),
    "segmentation.refine_iterations": Range(0, 10_000, "rounds"),
    "segmentation.shared_scale": Range(0, 1, "0 or 1"),
    "segmentation.max_links": Range(1, 10_000, "links"),
    "segmentation.min_links": Range(1, 10_000, "links (1 accepts a single rigid body)"),
    "segmentation.restarts": Range(1, 10_000, "runs"),
    "segmentation.selection_factor": Range(0, 1000, "times the median residual", **_OPEN),
    "segmentation.covariances": Range(0, 1, "0 or 1"),
    # --- joints (artrecon.joints.JointConfig)
    "joints.revolute_min_angle": Range(0, math.pi / 2, "radians", **_OPEN),
    "joints.adjacency_distance": Range(0, 100, "a fraction of the scene size", **_OPEN),
    "joints.misfit_weight": Range(0, 1e6, "a weight"),
    "joints.axis_gap_weight": Range(0, 1e6, "a weight"),
    "joints.contact_margin": Range(0, 100, "a fraction of the scene size"),
    # --- surface (artrecon.surface_fit.SurfaceConfig)
    "surface.enabled": Range(0, 1, "0 or 1"),
    "surface.weight": Range(0, 100, "share of an independent point's information"),
    "surface.reach": Range(0, 1000, "dense spacings", **_OPEN),
    "surface.max_normal_angle_deg": Range(0, 180, "degrees", **_OPEN),
    "surface.loss_scale": Range(0, 1000, "robust standard deviations", **_OPEN),
    "surface.iterations": Range(1, 1000, "rounds"),
    "surface.min_pairs": Range(3, 10**9, "pairs"),
    # --- photometric (artrecon.match_refine.PhotometricConfig)
    "photometric.enabled": Range(0, 1, "0 or 1"),
    "photometric.half_size": Range(1, 50, "pixels"),
    "photometric.blur": Range(0, 10, "pixels"),
    "photometric.min_ncc": Range(-1, 1, "correlation"),
    "photometric.max_shift": Range(0, 100, "pixels", **_OPEN),
    "photometric.iterations": Range(1, 1000, "rounds"),
    "photometric.max_residual": Range(0, 100, "pixels", **_OPEN),
    "photometric.min_views": Range(2, 10**6, "views"),
    "photometric.min_contrast": Range(0, 255, "grey levels"),
    # --- refine (artrecon.refine.RefineConfig)
    "refine.enabled": Range(0, 1, "0 or 1"),
    "refine.loss_scale": Range(0, 1000, "standard deviations", **_OPEN),
    "refine.rounds": Range(1, 100, "rounds"),
    "refine.max_iterations": Range(1, 10_000, "iterations"),
    "refine.max_change_sigma": Range(0, 1e6, "standard deviations", **_OPEN),
    "refine.adopt": Range(0, 1, "0 or 1"),
    # --- assign (artrecon.assign.AssignConfig)
    "assign.residual_factor": Range(0, 1000, "times the link's residual", **_OPEN),
    "assign.spacing_factor": Range(0, 1000, "point spacings", **_OPEN),
    "assign.zbuffer_cell": Range(1, 256, "pixels"),
    "assign.depth_tolerance": Range(0, 0.5, "a fraction of the depth", **_OPEN),
    "assign.violation_window": Range(1, 63, "z-buffer cells, odd"),
    "assign.violations_saturate": Range(1, 10_000, "cameras"),
    "assign.cost_no_fit": Range(0, 1000, "a cost"),
    "assign.cost_violation": Range(0, 1000, "a cost"),
    "assign.cost_photo": Range(0, 1000, "a cost"),
    "assign.photo_unknown": Range(0, 1, "a share of cost_photo, as (1 - NCC) / 2"),
    "assign.cost_match": Range(0, 1000, "a cost"),
    "assign.match_reach": Range(0, 1e6, "point spacings", **_OPEN),
    "assign.smoothness": Range(0, 1000, "a Potts weight"),
    "assign.neighbours": Range(1, 256, "graph neighbours"),
    "assign.neighbour_radius": Range(0, 1000, "point spacings", **_OPEN),
    "assign.expansion_cycles": Range(1, 1000, "passes"),
    "assign.passes": Range(1, 100, "passes"),
    "assign.patch_half": Range(1, 64, "samples"),
    "assign.patch_step_px": Range(0, 100, "pixels", **_OPEN),
    # --- freespace (artrecon.freespace.FreeSpaceConfig)
    "freespace.enabled": Range(0, 1, "0 or 1"),
    "freespace.colour_tolerance": Range(0, 765, "RGB levels, summed over the channels", **_OPEN),
    "freespace.min_share": Range(0, 1, _FRACTION, **_OPEN),
    "freespace.margin": Range(0, 10, "a fraction of the camera distance"),
    "freespace.max_cells": Range(1000, 10_000_000, "mosaic cells"),
    "freespace.height_search": Range(0, 1, "a fraction of the camera distance"),
    "freespace.height_samples": Range(100, 1_000_000, "places on the plane"),
    "freespace.min_views": Range(1, 10_000, "views"),
    # --- confidence (artrecon.confidence.ConfidenceConfig)
    "confidence.min_link_inliers": Range(3, 10_000_000, "matches"),
    "confidence.min_motion_snr": Range(0, 1e6, "times the noise"),
    "confidence.max_axis_spread_deg": Range(0, 180, "degrees", **_OPEN),
    "confidence.max_point_spread": Range(0, 100, "a fraction of the scene size", **_OPEN),
    "confidence.min_type_agreement": Range(0, 1, _FRACTION),
    "confidence.bootstrap_samples": Range(10, 1_000_000, "resamples"),
    "confidence.refuse": Range(0, 1, "0 or 1"),
}

#: Pairs of settings where the first may not exceed the second (checked after applying).
ORDERED = (
    ("dense.min_pair_angle_deg", "dense.max_pair_angle_deg"),
    ("segmentation.min_hypotheses", "segmentation.max_hypotheses"),
    ("segmentation.min_links", "segmentation.max_links"),
)


def parse_settings(items: list[str], example: str = "dense.downsample=1"
                   ) -> dict[str, float | str]:
    """``["dense.downsample=1", "sfm.matching=exhaustive"]`` -> ``{"dense.downsample": 1.0,
    "sfm.matching": "exhaustive"}``: the ``--set STAGE.FIELD=VALUE`` items of a command line,
    numbers as float, other values as text (a list such as ``20,40,60`` too: its row,
    :class:`ListOf`, splits it; InputError, naming ``example``, if an item is not
    STAGE.FIELD=VALUE; names, kinds and ranges are checked by :func:`apply_settings`)."""
    out: dict[str, float | str] = {}
    for item in items:
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or not key or not value:
            raise InputError(f"--set {item!r}: expected STAGE.FIELD=VALUE, e.g. {example}")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def check_setting(key: str, value, default,
                  ranges: Mapping[str, Range | Choice | ListOf] = RANGES):
    """``value`` checked against the row of ``key`` and converted to the kind of ``default``.

    Parameters
    ----------
    key : str
        ``"stage.field"``.
    value : float, int, bool, str, or a list or tuple (a :class:`ListOf` row)
        As given (the command line passes numbers as float, text as str; a list row takes
        comma-separated text, one number, or a sequence).
    default
        The field's default value (its kind: bool, int, float, str, or a tuple of numbers).
    ranges : dict
        The table of rows (default :data:`RANGES`, the reconstruction's; the simulation's
        capture has its own).

    Returns
    -------
    bool, int, float, str, or a tuple (a :class:`ListOf` row: of the kind of the default's
    values)

    Raises
    ------
    InputError
        No row for the field, a value of the wrong kind, not finite, or out of range (a list:
        a value of it, naming which, or too many or too few values); the message gives the
        valid range.
    """
    row = ranges.get(key)
    if row is None:
        raise InputError(f"setting {key!r} cannot be set (it has no checked range)")
    if isinstance(row, ListOf):
        return _check_list(key, value, default, row)
    if isinstance(row, Choice):
        if not isinstance(value, str) or value not in row.options:
            raise InputError(f"setting {key}={_num(value)}: {key} takes {row.text()}, default "
                             f"{default!r}")
        return value
    if isinstance(value, str):
        low = value.strip().lower()
        if isinstance(default, bool) and low in ("true", "false"):
            value = low == "true"
        else:
            try:
                value = float(value)
            except ValueError:
                raise InputError(f"setting {key}={value}: not a number; {key} takes "
                                 f"{row.text()}, default {_num(default)}") from None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"setting {key}={value!r}: not a number; {key} takes {row.text()}, "
                         f"default {_num(default)}") from None
    if not math.isfinite(number):
        raise InputError(f"setting {key}={_num(value)}: not a finite number; {key} takes "
                         f"{row.text()}, default {_num(default)}")
    if isinstance(default, bool):
        if number not in (0.0, 1.0):
            raise InputError(f"setting {key}={_num(value)}: not a boolean; {key} takes 0 (off) "
                             f"or 1 (on), default {int(default)}")
        return bool(number)
    if isinstance(default, int):
        if number != int(number):
            raise InputError(f"setting {key}={_num(value)}: not a whole number; {key} takes "
                             f"{row.text()}, default {_num(default)}")
        number = int(number)
    if not row.holds(number):
        raise InputError(f"setting {key}={_num(value)}: out of range; {key} takes "
                         f"{row.text()}, default {_num(default)}")
    return number if isinstance(default, int) else float(number)


def _check_list(key: str, value, default: tuple, row: ListOf) -> tuple:
    """:func:`check_setting` of a list setting: every value in ``row.item``, as many as
    ``row.length``, converted to the kind of the default's values."""
    if row.may_be_empty and (isinstance(value, str) and value.strip().lower() == "none"
                             or isinstance(value, (list, tuple)) and len(value) == 0):
        return ()
    if isinstance(value, str):
        parts = [part.strip() for part in value.split(",")]
    elif isinstance(value, (list, tuple)):
        parts = list(value)
    else:  # one number: the command line reads "30" as 30.0
        parts = [value]
    given = ",".join(_shown(part) for part in parts)
    kind = type(default[0]) if default else float

    def refuse(problem: str):
        raise InputError(f"setting {key}={given}: {problem}; {key} takes {row.text()}, default "
                         f"{','.join(_num(d) for d in default)}")

    if row.length is not None and len(parts) != row.length:
        refuse(f"{len(parts)} value{'s' if len(parts) != 1 else ''}, not {row.length}")
    if not parts:
        refuse("no value")
    out = []
    for i, part in enumerate(parts, 1):
        shown = f"value {i} ({_shown(part)})"
        if isinstance(part, str) and not part:
            refuse(f"value {i} is empty")
        try:
            number = float(part)
        except (TypeError, ValueError):
            number = None
        if number is None or isinstance(part, bool):
            refuse(f"{shown} is not a number")
        if not math.isfinite(number):
            refuse(f"{shown} is not a finite number")
        if kind is int and number != int(number):
            refuse(f"{shown} is not a whole number")
        if not row.item.holds(number):
            refuse(f"{shown} is out of range")
        out.append(int(number) if kind is int else float(number))
    return tuple(out)


def _shown(part) -> str:
    """A value of a list setting as the user wrote it (numbers as :func:`_num`)."""
    if isinstance(part, (int, float)) and not isinstance(part, bool):
        return _num(part)
    return str(part)


def apply_settings(config, settings: dict, ranges: Mapping[str, Range | Choice | ListOf] = RANGES,
                   ordered: tuple[tuple[str, str], ...] = ORDERED):
    """A copy of a config of stage configs (:class:`ReconstructConfig`, or another frozen
    dataclass whose fields are configs, with its own table ``ranges`` and ``ordered`` pairs)
    with ``settings`` (``{"stage.field": value}``) applied, each checked (:func:`check_setting`);
    InputError for an unknown stage or field, a bad value, or a pair of :data:`ORDERED` fields
    in the wrong order."""
    stages = {f.name: getattr(config, f.name) for f in fields(config)}
    changed: dict[str, dict] = {}
    for key, value in settings.items():
        stage, _, name = key.partition(".")
        if stage not in stages or not name:
            raise InputError(f"setting {key!r}: name it stage.field with a stage of "
                             f"{sorted(stages)} (e.g. {next(iter(ranges))})")
        sub = stages[stage]
        known = {f.name for f in fields(sub)}
        if name not in known:
            raise InputError(f"setting {key!r}: {type(sub).__name__} has no field {name!r}; its "
                             f"fields are {sorted(known)}")
        changed.setdefault(stage, {})[name] = check_setting(key, value, getattr(sub, name),
                                                            ranges)
    try:
        out = replace(config, **{stage: replace(stages[stage], **kw)
                                 for stage, kw in changed.items()})
    except ValueError as exc:  # a stage's own check (e.g. DenseConfig.downsample >= 1)
        raise InputError(f"settings {settings}: {exc}") from exc
    for first, second in ordered:
        a = getattr(getattr(out, first.split(".")[0]), first.split(".")[1])
        b = getattr(getattr(out, second.split(".")[0]), second.split(".")[1])
        if a > b and (first in settings or second in settings):
            raise InputError(f"settings: {first} ({_num(a)}) may not exceed {second} "
                             f"({_num(b)}); change one of them")
    return out


@dataclass(frozen=True)
class ReconstructConfig:
    """Settings of every stage."""

    sfm: SfMConfig = field(default_factory=SfMConfig)
    dense: DenseConfig = field(default_factory=DenseConfig)
    region: RegionConfig = field(default_factory=RegionConfig)
    match: MatchConfig = field(default_factory=MatchConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    joints: JointConfig = field(default_factory=JointConfig)
    assign: AssignConfig = field(default_factory=AssignConfig)
    freespace: FreeSpaceConfig = field(default_factory=FreeSpaceConfig)
    confidence: ConfidenceConfig = field(default_factory=ConfidenceConfig)
    guided: GuidedConfig = field(default_factory=GuidedConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    photometric: PhotometricConfig = field(default_factory=PhotometricConfig)


def with_settings(config: ReconstructConfig, settings: dict[str, float | int | bool | str]
                  ) -> ReconstructConfig:
    """``config`` with some settings changed, each named ``"stage.field"`` as in
    :class:`ReconstructConfig` (e.g. ``{"dense.downsample": 1}``: full-resolution stereo for
    thin objects). Each value is checked against the field's range and converted to its type
    (:func:`apply_settings`); an unknown stage or field, or a value of the wrong
    kind, not finite or out of range, raises InputError naming the valid range."""
    return apply_settings(config, settings)


def jsonable(obj):
    """A record of a config (``dataclasses.asdict`` of one) as plain JSON values: dicts and
    sequences walked (tuples become lists), numpy scalars as Python numbers, anything else not
    JSON as its ``str``. The model's metadata records its config so."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)
