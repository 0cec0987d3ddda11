"""The typed record of ``results.json``: the file's schema, as frozen dataclasses.

The writers (:func:`sim.evaluate.report.write_results`, :func:`sim.evaluate.sweep_report.
write_sweep`) build the file from a :class:`Results` (:meth:`Results.to_json`); whatever reads a
results.json reads it through :meth:`Results.from_json` (:func:`read_results` for a file), which
refuses a file of another :data:`SCHEMA_VERSION` and names any key or value the record does not
hold. The record holds what the runner computes, nothing is recomputed here.

Schema (``schema_version`` 1)
-----------------------------
Top level, one of two layouts (:attr:`Results.layout`):

- ``scenes`` (one run per scene, the main job): ``{"schema_version", "scenes": {name:
  SceneRecord}, "meta": Meta}``;
- ``sweep`` (several runs of a scene: seeds, perturbations): ``{"schema_version", "meta": Meta,
  "runs": [RunRecord], "summary": [GroupSummary]}``.

:class:`Meta`: versions, seed (``seeds`` in a sweep), views per ring, poses, manipulate,
perturbation, capture settings (when set), command, date, scene hashes, the gate table, platform,
and ``sweep`` (backend, jobs, retries, wall time) when runs ran in parallel. :class:`SceneRecord`
is one scene's result (:func:`sim.evaluate.runner.evaluate_scene`): ``scene``, ``error`` and
``error_stage``, ``timings_s``, ``cached_stages``, the captures, the model's summary,
``registration``, the joints (:class:`JointRecord`, one per true moving joint), the kinematic
tree, ``segmentation``, the model's accuracy and completeness (``model``), the camera poses,
``manipulation`` (:class:`ManipulationRecord`, one :class:`ManipulationRun` per model joint), and
the verdict (``passed``, ``failed_gates``: :class:`sim.evaluate.gates.GateCheck`). Each field's
docstring says what it holds; units are in the names (``_deg``, ``_mm``, ``_s``, ``_n``).

A key the writer had not reached is absent rather than null (a scene that failed in its capture
has no ``segmentation``; a worker that died leaves only the error): every record remembers the
keys it was read with (``present``) and writes those again, so a file read and written again is
the same file. A record made in code (``present`` None) writes every field.

A sweep's ``OUT/runs/<run id>/run.json`` (what ``--resume`` reads) is one :class:`RunRecord`
with the ``schema_version`` beside its keys: ``{"schema_version", "id", "group", "spec", ...}``
(:func:`run_file` writes it, :func:`read_run` reads it and refuses it as :meth:`Results.from_json`
refuses a results.json).

Any change of a key (added, removed, renamed, another meaning) raises :data:`SCHEMA_VERSION`.

How a record is read from and written to JSON (every key checked against the field's
annotation, the keys read remembered) is :mod:`sim.evaluate.json_record`'s; this module is the
schema.
"""

from __future__ import annotations

import json
import typing
from dataclasses import dataclass
from pathlib import Path

from sim.evaluate.gates import GateCheck
from sim.evaluate.json_record import JsonRecord, SchemaError, kind

#: The version of the results.json schema this code writes and reads.
SCHEMA_VERSION = 1


@dataclass(frozen=True, kw_only=True)
class _Record(JsonRecord):
    """A JSON object of results.json: its fields are its keys."""

    schema_note: typing.ClassVar[str] = f"results.json schema_version {SCHEMA_VERSION}"


# ---------------------------------------------------------------------------- a scene


@dataclass(frozen=True, kw_only=True)
class JointRecord(_Record):
    """One true moving joint against the estimate paired with it
    (:func:`sim.evaluate.scoring.score_joints`); the estimate's figures are null when none was
    paired."""

    name: str
    """the true joint"""
    type_true: str | None = None
    type_estimated: str | None = None
    estimated_joint: str | None = None
    """the model's joint paired with it (null: missed)"""
    type_correct: bool | None = None
    axis_angle_deg: float | None = None
    axis_position_mm: float | None = None
    """revolute joints: distance between the estimated and the true axis"""
    state_error: float | None = None
    """in :attr:`state_error_unit`"""
    state_error_unit: str | None = None
    """``deg`` (revolute) or ``mm`` (prismatic), also of the two states"""
    state_true: float | None = None
    state_estimated: float | None = None
    angle_to_table_normal_deg: float | None = None
    angle_to_table_normal_true_deg: float | None = None
    confidence: dict | None = None
    """artrecon's own evidence for the estimate (artrecon.confidence)"""
    refinement: dict | None = None
    """the articulated bundle adjustment's verdict, 1-sigma uncertainty (``sigma_axis_deg``,
    ``sigma_position_mm``, ``sigma_state`` in :attr:`state_error_unit`) and the errors of the
    joint before (``initial``) and after it (``refined``) (sim.evaluate.scoring.score_refinement)"""
    links_swapped: bool | None = None
    """the model took the true child as the fixed link (the state is compared inverted)"""
    paired_by_links: bool | None = None
    """paired by the links it joins (else by axis geometry)"""
    passes: bool | None = None
    """meets every joint gate"""


@dataclass(frozen=True, kw_only=True)
class InventedJoint(_Record):
    """An estimated joint paired with no true one."""

    name: str
    type: str | None = None
    angle_to_table_normal_deg: float | None = None


@dataclass(frozen=True, kw_only=True)
class CaptureSummary(_Record):
    """One configuration's capture (``capture_a``, ``capture_b``)."""

    n_planned: int | None = None
    n_captured: int | None = None
    max_fk_position_error_mm: float | None = None
    max_fk_rotation_error_deg: float | None = None
    survey_centre_error_mm: float | None = None
    """the survey's sphere (what the capture looked at) against the true one: centre, mm"""
    survey_radius_ratio: float | None = None
    """and radius, surveyed over true"""


@dataclass(frozen=True, kw_only=True)
class ModelSummary(_Record):
    """The reconstruction's size (its metadata); per configuration where keyed ``a``/``b``."""

    links: int | None = None
    joints: int | None = None
    registered_images: dict[str, int] | None = None
    num_images: dict[str, int] | None = None
    sparse_points: dict[str, int] | None = None
    dense_points: dict[str, int] | None = None
    matches: int | None = None
    match_outliers: int | None = None
    pose_agreement: dict | None = None
    """per configuration, how well the FK poses agree with the images (artrecon.sfm)"""


@dataclass(frozen=True, kw_only=True)
class TruthError(_Record):
    """A registration route against the true registration."""

    rotation_deg: float | None = None
    translation_mm: float | None = None
    """RMS over the model's points ..."""
    max_translation_mm: float | None = None
    """... and largest"""
    scale_percent: float | None = None


@dataclass(frozen=True, kw_only=True)
class RegistrationRecord(_Record):
    """The registration: artrecon's report (artrecon.register, ``registration.json``) and each
    route's error against the truth."""

    chosen_route: str | None = None
    format: str | None = None
    route: str | None = None
    T_robot_model: dict | None = None
    """rotation, translation, scale of the chosen similarity"""
    scale_m_per_unit: float | None = None
    routes: dict[str, dict] | None = None
    """per route its report (inliers, residuals, images used) and similarity"""
    agreement: dict | None = None
    """how far the two routes lie apart, and the limits"""
    truth_errors: dict[str, TruthError] | None = None
    """per route (``camera_centres``, ``pnp``)"""


@dataclass(frozen=True, kw_only=True)
class SegmentationRecord(_Record):
    """The model's points against the rendered link labels (:func:`sim.evaluate.scoring.
    score_scene`)."""

    method: str | None = None
    points: int | None = None
    off_surface_share: float | None = None
    """points no view holds on the object (left out of the accuracy)"""
    scored_in: dict[str, int] | None = None
    """points scored in configuration ``a`` and ``b``"""
    accuracy_in: dict[str, float | None] | None = None
    accuracy_nearest_surface_at_a: float | None = None
    """the earlier figure: every point at A, nearest true surface"""
    model_links: int | None = None
    true_links: int | None = None
    points_per_link: list[int] | None = None


@dataclass(frozen=True, kw_only=True)
class SurfaceScore(_Record):
    """Accuracy and completeness on a part of the true surface."""

    accuracy_median_mm: float | None = None
    accuracy_p90_mm: float | None = None
    completeness: float | None = None
    n_samples: int | None = None
    n_points: int | None = None


@dataclass(frozen=True, kw_only=True)
class ModelScore(_Record):
    """The model's points against the true surfaces: overall, on the side hidden from the last
    view of A and on the side it saw."""

    accuracy_median_mm: float | None = None
    accuracy_p90_mm: float | None = None
    completeness: float | None = None
    """share of true surface samples within ``radius_mm`` of a model point"""
    hidden: SurfaceScore | None = None
    visible: SurfaceScore | None = None
    hidden_share_of_surface: float | None = None
    final_view: str | None = None
    n_samples: int | None = None
    radius_mm: float | None = None


@dataclass(frozen=True, kw_only=True)
class PoseErrors(_Record):
    """Camera poses of A (SfM, registered) against the true ones."""

    position_median_mm: float | None = None
    position_max_mm: float | None = None
    rotation_median_deg: float | None = None
    rotation_max_deg: float | None = None
    n: int | None = None
    images_of_a: int | None = None


@dataclass(frozen=True, kw_only=True)
class ManipulationRun(_Record):
    """One model joint moved as the model says, scored along the true joint
    (:func:`sim.evaluate.scoring.score_manipulation`)."""

    model_joint: str
    true_joint: str | None = None
    error: str | None = None
    unit: str | None = None
    """``deg`` or ``mm``, of requested and achieved"""
    requested: float | None = None
    grasp_point: list[float] | None = None
    grasp_normal: list[float] | None = None
    grasp_hidden: bool | None = None
    grasp_visibility: str | None = None
    grasp_body: str | None = None
    grasp_lost: bool | None = None
    grasp_lost_at: float | None = None
    planned_in: str | None = None
    arm_contacts: list | None = None
    grasp_roll_deg: float | None = None
    candidates: dict | None = None
    """grasp candidates: how many, hidden, usable, rejected; ``missed``: the grasps before this
    one that closed on nothing (their points and messages)"""
    peak_force_n: float | None = None
    rms_force_n: float | None = None
    peak_torque_nm: float | None = None
    grip_limits: dict | None = None
    tracking_max_deg: float | None = None
    path_error_max_mm: float | None = None
    moved: dict[str, float] | None = None
    """every joint of the scene that moved, by how much (rad or m)"""
    achieved: float | None = None
    relative_error: float | None = None
    needed_force_n: float | None = None
    """the force the true joint needs with this grasp and motion"""
    force_at_gate_tolerance_n: float | None = None
    reference: dict | None = None
    """the replays along the true joint that give the two forces above"""
    force_limit_n: float | None = None
    passes: bool | None = None
    reason: str | None = None
    """why an invented joint's run has no figures"""


@dataclass(frozen=True, kw_only=True)
class ManipulationRecord(_Record):
    """Every joint of the model moved in turn, and the worst figures over them."""

    runs: list[ManipulationRun] | None = None
    joints_moved: int | None = None
    requested: float | None = None
    achieved: float | None = None
    unit: str | None = None
    relative_error: float | None = None
    peak_force_n: float | None = None
    grasp_hidden_any: bool | None = None
    passes: bool | None = None
    reason: str | None = None
    q_start: list[float] | None = None
    q_start_from: str | None = None


@dataclass(frozen=True, kw_only=True)
class SceneRecord(_Record):
    """One scene's result (:func:`sim.evaluate.runner.evaluate_scene`, or a worker's failure
    that stands for it)."""

    scene: str
    error: str | None = None
    """``stage: Type: message`` of the stage that failed (null: none)"""
    error_stage: str | None = None
    timings_s: dict[str, float] | None = None
    """per stage (:data:`sim.evaluate.config.STAGES`), as built when cached"""
    cached_stages: list[str] | None = None
    joints: list[JointRecord] | None = None
    segmentation_accuracy: float | None = None
    manipulation: ManipulationRecord | None = None
    scene_file: str | None = None
    scene_hash: str | None = None
    perturb_a: dict | None = None
    """robustness runs: what the perturbation did to configuration A's set"""
    capture_a: CaptureSummary | None = None
    perturb_b: dict | None = None
    capture_b: CaptureSummary | None = None
    reconstruct_timings_s: dict[str, float] | None = None
    perturb_matches: dict | None = None
    model_summary: ModelSummary | None = None
    registration: RegistrationRecord | None = None
    invented_joints: list[InventedJoint] | None = None
    static_joints: list[str] | None = None
    n_estimated_joints: int | None = None
    n_true_moving_joints: int | None = None
    pairs: list[list[str]] | None = None
    """(estimated, true) joint names"""
    tree_correct: bool | None = None
    link_correspondence: dict[str, str] | None = None
    """model link: true link"""
    segmentation: SegmentationRecord | None = None
    model: ModelScore | None = None
    camera_pose_error: PoseErrors | None = None
    scale_error_pct: float | None = None
    traceback: str | None = None
    wall_s: float | None = None
    second_process_cpu_s: float | None = None
    """CPU seconds the scene's second process used over the scene (kept across scenes, it is no
    finished child of the evaluating process: its CPU is read from /proc)"""
    passed: bool | None = None
    failed_gates: list[GateCheck] | None = None
    pictures_error: str | None = None
    attempts: int | None = None
    """a sweep's run that needed more than one"""


# ---------------------------------------------------------------------------- a run, a sweep


@dataclass(frozen=True, kw_only=True)
class SweepMeta(_Record):
    """How a sweep's runs ran."""

    backend: str | None = None
    jobs: int | None = None
    address: str | None = None
    retries: int | None = None
    runs: int | None = None
    wall_s: float | None = None


@dataclass(frozen=True, kw_only=True)
class Meta(_Record):
    """The run's metadata (:func:`sim.evaluate.runner.run_meta`)."""

    versions: dict[str, str] | None = None
    seed: int | None = None
    """the seed (a sweep: ``seeds``)"""
    views_per_ring: int | None = None
    poses: str | None = None
    manipulate: bool | None = None
    perturbation: dict | None = None
    """the perturbation's changed fields (none: ``{}``)"""
    capture_settings: dict | None = None
    """the capture settings off their defaults (``--set capture.FIELD=VALUE``, ``views.``;
    absent when none is set)"""
    command: str | None = None
    date: str | None = None
    scene_hashes: dict[str, str | None] | None = None
    gates: dict[str, float] | None = None
    """the gate table (:data:`sim.evaluate.gates.GATES`)"""
    platform: str | None = None
    sweep: SweepMeta | None = None
    seeds: list[int] | None = None
    perturbations: dict[str, dict] | None = None
    """robustness sweeps: per perturbation its title, unit and neutral strength"""


@dataclass(frozen=True, kw_only=True)
class RunSpecRecord(_Record):
    """What decides a run's figures (:meth:`sim.evaluate.sweep.RunSpec.describe`)."""

    scene: str
    config: dict | None = None
    """the EvalConfig fields that change figures, the perturbation's changed fields"""
    perturbation: str | None = None
    strength: float | None = None
    label: str | None = None


@dataclass(frozen=True, kw_only=True)
class RunRecord(_Record):
    """One run of a sweep (also its ``run.json``)."""

    id: str
    group: str | None = None
    spec: RunSpecRecord | None = None
    code: str | None = None
    """hash of the code that ran it (absent: not run)"""
    status: str | None = None
    """``passed``, ``failed``, ``died`` or ``not run``"""
    attempts: int | None = None
    worker: dict | None = None
    """host, pid, wall_s"""
    dir: str | None = None
    """its report folder, relative to the sweep's"""
    result: SceneRecord | None = None


@dataclass(frozen=True, kw_only=True)
class FigureSummary(_Record):
    """One gated figure over the seeds of a group."""

    unit: str | None = None
    gate: float | None = None
    values: dict[str, float | None] | None = None
    """per seed"""
    n: int | None = None
    missing: int | None = None
    median: float | None = None
    worst: float | None = None
    spread: float | None = None
    worst_passes: bool | None = None


@dataclass(frozen=True, kw_only=True)
class GroupSummary(_Record):
    """Runs of one scene and setting, seeds apart (:func:`sim.evaluate.sweep_report.
    sweep_summary`)."""

    group: str
    scene: str | None = None
    perturbation: str | None = None
    strength: float | None = None
    label: str | None = None
    seeds: list[int] | None = None
    runs: int | None = None
    passed: int | None = None
    failed: list[str] | None = None
    figures: dict[str, FigureSummary] | None = None


# ---------------------------------------------------------------------------- the file


@dataclass(frozen=True, kw_only=True)
class Results(_Record):
    """A whole results.json: ``scenes`` and ``meta``, or a sweep's ``meta``, ``runs`` and
    ``summary``."""

    schema_version: int = SCHEMA_VERSION
    scenes: dict[str, SceneRecord] | None = None
    meta: Meta
    runs: list[RunRecord] | None = None
    summary: list[GroupSummary] | None = None

    def __post_init__(self):
        if (self.scenes is None) == (self.runs is None):
            raise SchemaError("results.json holds either scenes (one run per scene) or runs "
                              "and summary (a sweep), not "
                              + ("both" if self.scenes is not None else "neither"))
        if self.present is None:  # the layout's keys, not the other layout's nulls
            keys = ("scenes",) if self.scenes is not None else ("runs", "summary")
            object.__setattr__(self, "present", frozenset(("schema_version", "meta", *keys)))

    @property
    def layout(self) -> str:
        """``"scenes"`` or ``"sweep"``."""
        return "scenes" if self.scenes is not None else "sweep"

    @classmethod
    def from_json(cls, data, where: str = "results.json") -> Results:
        """The record of a parsed results.json; SchemaError for a file of another
        schema_version (or none: written before the schema had one) and for any key or value
        the record does not hold."""
        _check_version(data, where)
        return super().from_json(data, where)


def _check_version(data, where: str) -> None:
    """SchemaError unless ``data`` is an object of this code's :data:`SCHEMA_VERSION`."""
    if not isinstance(data, dict):
        raise SchemaError(f"{where}: expected an object, got {kind(data)}")
    version = data.get("schema_version")
    if version != SCHEMA_VERSION:
        written = ("has no schema_version: it was written before sim.evaluate versioned "
                   "its results" if version is None else
                   f"is of schema_version {version!r}")
        raise SchemaError(f"{where} {written}; this code reads schema_version "
                          f"{SCHEMA_VERSION} (sim/evaluate/record.py). Run the evaluation "
                          "again with this code, or read the file with the code that wrote "
                          "it.")


def _read(path: Path):
    try:
        return json.loads(path.read_text())
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
        raise SchemaError(f"{path}: not JSON ({err})") from err


def build(results: dict) -> Results:
    """The record of the results a writer holds (plain JSON values: the runner's dicts after
    :func:`sim.evaluate.report.jsonable_scene`), at this code's :data:`SCHEMA_VERSION`."""
    return Results.from_json({"schema_version": SCHEMA_VERSION, **results})


def read_results(path: str | Path) -> Results:
    """The record of a results.json file (SchemaError: another version, or not this schema)."""
    path = Path(path)
    return Results.from_json(_read(path), str(path))


def run_file(run: RunRecord) -> dict:
    """The JSON of a sweep's ``run.json``: the run's keys after the ``schema_version``."""
    return {"schema_version": SCHEMA_VERSION, **run.to_json()}


def read_run(path: str | Path) -> RunRecord:
    """The record of a sweep's ``run.json`` (:func:`run_file`).

    Raises
    ------
    OSError
        The file cannot be read.
    SchemaError
        Not JSON, another schema_version (or none: written before run.json had one), or a key
        or value :class:`RunRecord` does not hold; the message names the file and where in it.
    """
    path = Path(path)
    data = _read(path)
    _check_version(data, str(path))
    return RunRecord.from_json({k: v for k, v in data.items() if k != "schema_version"},
                               str(path))
