"""Turn a :class:`~sim.author.source.SourceObject` into a scene of the harness.

What :func:`import_object` does, in order (see ``scenes/README.md`` for the conventions it meets):

1. read the URDF or MJCF (:mod:`sim.author.urdf`, :mod:`sim.author.mjcf`);
2. choose configuration A (each joint at 0, or at the limit nearest 0) and scale the object so
   that its largest extent at A is ``size`` (or by a given factor);
3. choose configuration B (given per joint, or a visible motion of every joint inside its range:
   :attr:`ImportConfig.revolute_motion`, :attr:`ImportConfig.prismatic_motion`);
4. place it on the table centre: centred in x and y at A, its lowest point over A and B just above
   the table top; refuse an object that would overhang the table;
5. texture every link: its visible meshes merged, UV-unwrapped and given their own non-repeating
   texture (:func:`sim.assets.texture_mesh`);
6. collision shapes: each collision mesh's oriented box (or its convex hull, a box where the
   hull is flat), primitives kept, all with :attr:`ImportConfig.density`; contacts between the
   object's links excluded (the joints guide them);
7. joint friction and damping from the gravity load each joint carries at A and B;
8. write ``OUT/NAME.xml`` and ``OUT/assets/NAME_*`` with the stage beside them (its copy, its
   assets and the arm: :mod:`sim.author.stage`, so that the folder holds everything it needs),
   validate the scene
   (:func:`sim.scene.load_scene`, a second of physics in A and in B without MuJoCo warnings) and
   check both configurations
   hold; raise the friction of a joint that creeps. The files appear only when all of this
   passes.
"""

from __future__ import annotations

import logging
import math
import re
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from sim.author.config import UP_AXES, ImportConfig
from sim.author.mjcf import read_mjcf
from sim.author.source import (
    AuthorError,
    SourceObject,
    pose,
    transform_points,
)
from sim.author.stage import is_stage_copy, stage_copy
from sim.author.urdf import read_urdf
from sim.author.writer import (
    SceneWriter,
    joint_range,
    sanitize,
)
from sim.scene import BUNDLED_SCENES_DIR, SceneError, load_scene, physics_warnings

log = logging.getLogger(__name__)

#: Height (m) of the object's lowest point above the table top: the bundled objects float 0.5 mm
#: above it, so that nothing touches the table at rest (no contact to excite the physics).
TABLE_CLEARANCE = 0.0005
#: Largest distance (m) from the table centre any part may reach in A or B: the table's radius
#: (0.35 m) less 2 cm, so nothing overhangs its edge.
MAX_FOOTPRINT_RADIUS = 0.33
#: Drift allowed over :data:`HOLD_SECONDS` of physics in each configuration (as
#: tests/test_scenes.py demands of every scene).
HOLD_TOLERANCE = {"revolute": np.deg2rad(0.5), "prismatic": 1e-3}
HOLD_SECONDS = 1.0
#: A joint's friction loss (sim.author.writer.FRICTION_OVER_LOAD times its load) is raised by
#: this factor per failed hold check, at most HOLD_TRIES times.
HOLD_FRICTION_GROWTH = 2.0
HOLD_TRIES = 4
@dataclass
class ImportResult:
    """What :func:`import_object` wrote and chose."""

    scene: Path
    """the scene file"""
    assets: list[Path]
    """the files in ``assets/`` it wrote"""
    scale: float
    """source units to metres"""
    config_a: dict[str, float]
    config_b: dict[str, float]
    notes: list[str]
    """what the import changed, chose or left out"""
    stage: list[Path] = field(default_factory=list)
    """the files of the stage it wrote beside the scene (the stage copy, its assets, the arm in
    ``robots/``): none where the folder has them already"""


# ------------------------------------------------------------------------------- reading


def read_source(path: Path, body: str | None = None) -> SourceObject:
    """Read a URDF or an MJCF file (told apart by the root element)."""
    path = Path(path)
    if not path.is_file():
        raise AuthorError(f"{path}: no such file; give a URDF (e.g. PartNet-Mobility's "
                          f"mobility.urdf) or an MJCF file")
    head = path.read_text(errors="replace")[:4096]
    head = re.sub(r"<!--.*?-->", "", re.sub(r"<\?.*?\?>", "", head, flags=re.S), flags=re.S)
    m = re.search(r"<\s*([A-Za-z_][\w.-]*)", head)
    root = m.group(1) if m else ""
    if root == "robot":
        if body is not None:
            raise AuthorError(f"{path}: --body chooses a body of an MJCF file; a URDF's object "
                              f"is its whole tree")
        return read_urdf(path)
    if root == "mujoco":
        return read_mjcf(path, body)
    raise AuthorError(f"{path}: the root element is <{root}>, neither <robot> (URDF) nor "
                      f"<mujoco> (MJCF); give one of those")


def default_name(path: Path) -> str:
    """Scene name from a source path: ``partnet_<folder>`` for a ``mobility.urdf``."""
    if path.stem == "mobility":  # PartNet-Mobility: one folder per object, named by its id
        return sanitize(f"partnet_{path.parent.name}")
    return sanitize(path.stem)


# ------------------------------------------------------------------------------- choices


def default_a(j, scale: float = 1.0) -> float:
    """Configuration A of a joint: 0 if inside its range, else the limit nearest 0."""
    lo, hi = joint_range(j, scale)
    return float(min(max(0.0, lo), hi))


def default_b(j, a: float, motion: float, scale: float, notes: list[str]) -> float:
    """Configuration B of a joint: ``a`` moved by ``motion`` where the range has room (forward
    first), else as far as the range allows (noted)."""
    lo, hi = joint_range(j, scale)
    if a + motion <= hi + 1e-12:
        return a + motion
    if a - motion >= lo - 1e-12:
        return a - motion
    b = hi if hi - a >= a - lo else lo
    unit, k = ("deg", 180 / math.pi) if j.type == "revolute" else ("cm", 100.0)
    notes.append(f"joint {j.name!r}: its range [{lo * k:.1f}, {hi * k:.1f}] {unit} allows only "
                 f"{abs(b - a) * k:.1f} {unit} of motion (the method sees "
                 f"{motion * k:.0f} {unit} best)")
    log.warning("%s", notes[-1])
    return float(b)


def _check_values(obj: SourceObject, values: Mapping[str, float], which: str,
                  scale: float) -> None:
    names = [j.name for j in obj.joints]
    for name, v in values.items():
        if name not in names:
            raise AuthorError(f"{obj.path}: --config-{which} names the joint {name!r}, which the "
                              f"object does not have; its joints are {names}")
        j = obj.joints[names.index(name)]
        lo, hi = joint_range(j, scale)
        if not lo - 1e-9 <= v <= hi + 1e-9:
            unit = "rad" if j.type == "revolute" else "m"
            raise AuthorError(f"{obj.path}: --config-{which} {name}={v:g} {unit} lies outside "
                              f"the joint's range [{lo:g}, {hi:g}] {unit} (after scaling); fix: "
                              f"choose a value inside it")


def _visual_points(obj: SourceObject, values: Mapping[str, float], U: np.ndarray) -> np.ndarray:
    """Every visual vertex in the root frame turned up (source units) at joint values."""
    poses = obj.link_poses(values)
    pts = [transform_points(pose(U) @ poses[name], m.vertices)
           for name, link in obj.links.items() for m in link.visuals]
    if not pts:
        raise AuthorError(f"{obj.path}: the object has no visible geometry; fix: give its links "
                          f"<visual> meshes (URDF) or visible geoms (MJCF, group 0-2)")
    return np.concatenate(pts)


# ------------------------------------------------------------------------------- the import


def import_object(source: str | Path, out_dir: str | Path,
                  config: ImportConfig | None = None) -> ImportResult:
    """Import an articulated object from a URDF or an MJCF file as a scene of the harness.

    Parameters
    ----------
    source : path
        ``mobility.urdf`` (PartNet-Mobility layout: OBJ meshes per part), any URDF, or an MJCF.
    out_dir : path
        Folder of the scene: ``OUT/NAME.xml`` and ``OUT/assets/NAME_*`` (created), anywhere on
        disk. The folder gets what the scene needs besides: a copy of the bundled stage
        (``stage.xml``, ``stage_panda.xml``), its assets and the arm (``robots/<arm>/``), unless
        it has them already (:mod:`sim.author.stage`). In ``scenes/`` itself the scene includes
        the bundled stage by name.
    config : ImportConfig, optional

    Returns
    -------
    ImportResult

    Raises
    ------
    AuthorError
        The source cannot be read or imported, a configuration is wrong, the object overhangs
        the table, the scene does not validate or a configuration does not hold; or the output
        files exist (pass ``overwrite``), or the folder's stage files differ from the harness's
        (pass ``overwrite``; never for a stage file the import did not write). Nothing is
        written then.
    """
    config = config or ImportConfig()
    source = Path(source).resolve()
    out_dir = Path(out_dir).resolve()
    obj = read_source(source, config.body)
    name = sanitize(config.name) if config.name else default_name(source)
    notes = list(obj.notes)
    U = UP_AXES[config.up] @ obj.R_world_root  # the source's world, turned to z up

    # scale at the default configuration A (each joint at 0 or its nearest limit)
    rest = {j.name: default_a(j) for j in obj.joints}
    if config.scale is not None:
        s = float(config.scale)
    else:
        extent = float(np.max(np.ptp(_visual_points(obj, rest, U), axis=0)))
        if extent <= 0:
            raise AuthorError(f"{source}: the object's visible geometry has no extent")
        s = config.size / extent
    # configurations in scene units (rad, metres after scaling)
    _check_values(obj, config.config_a, "a", s)
    _check_values(obj, config.config_b, "b", s)
    qa = {j.name: float(config.config_a.get(j.name, default_a(j, s))) for j in obj.joints}
    qb = {}
    for j in obj.joints:
        motion = config.revolute_motion if j.type == "revolute" else config.prismatic_motion
        qb[j.name] = float(config.config_b[j.name]) if j.name in config.config_b else \
            default_b(j, qa[j.name], motion, s, notes)
    src = {c: {j.name: q[j.name] / (s if j.type == "prismatic" else 1.0) for j in obj.joints}
           for c, q in (("a", qa), ("b", qb))}

    # placement: centred at A, lowest point over A and B just above the table
    pa, pb = _visual_points(obj, src["a"], U) * s, _visual_points(obj, src["b"], U) * s
    lo, hi = pa.min(0), pa.max(0)
    t = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2,
                  TABLE_CLEARANCE - min(pa[:, 2].min(), pb[:, 2].min())])
    reach = max(np.linalg.norm((p + t)[:, :2], axis=1).max() for p in (pa, pb))
    if reach > MAX_FOOTPRINT_RADIUS:
        raise AuthorError(f"{source}: at {s * 100:.3g} cm per source unit the object reaches "
                          f"{reach * 100:.1f} cm from the table centre in A or B (the table's "
                          f"radius is 35 cm); fix: a smaller --size (now "
                          f"{np.max(np.ptp(pa, axis=0)) * 100:.1f} cm), or a smaller motion "
                          f"with --config-b")
    # T_object_root as a similarity: p_object = s U p_root + t
    log.info("%s: scale %.4g, size at A %s cm", name, s, np.round(np.ptp(pa, 0) * 100, 1))

    xml_path = out_dir / f"{name}.xml"
    asset_dir = out_dir / "assets"
    refuse = ("fix: give another --name, another --out, or --overwrite to replace the files "
              "of the earlier import")
    if xml_path.exists() and not config.overwrite:
        raise AuthorError(f"{xml_path} exists (an earlier import named {name!r}?); {refuse}")
    bundled = out_dir == BUNDLED_SCENES_DIR.resolve()  # beside the stage: include it by name
    stage = stage_copy(config.arm)
    stage_writes = [] if bundled else _stage_writes(stage, out_dir, config.overwrite)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out_dir))
    try:
        writer = SceneWriter(obj, name, config, s, U, t, tmp, notes)
        writer.build()
        for rel, data in stage.files.items():  # validated with the stage beside it, as written
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            (tmp / rel).write_bytes(data)
        friction = writer.initial_friction(stage.head, qa, qb)
        for attempt in range(HOLD_TRIES + 1):
            writer.write(stage.head, qa, qb, friction)
            creeping = _validate(tmp / f"{name}.xml", qa, qb)
            if not creeping:
                break
            if attempt == HOLD_TRIES:
                raise AuthorError(
                    f"{source}: joints {sorted(creeping)} of the imported scene do not hold "
                    f"their configuration under gravity even with friction loss "
                    f"{ {k: round(friction[k], 3) for k in creeping} }; fix: a lighter object "
                    f"(--density) or configurations where gravity loads them less")
            for k in creeping:
                friction[k] *= HOLD_FRICTION_GROWTH
            notes.append(f"joints {sorted(creeping)} crept: friction loss raised to "
                         f"{ {k: round(friction[k], 3) for k in creeping} }")
        own = [p for p in (tmp / "assets").iterdir() if f"assets/{p.name}" not in stage.files]
        clash = [asset_dir / p.name for p in own if (asset_dir / p.name).exists()]
        if clash and not config.overwrite:
            raise AuthorError(f"{asset_dir}: {len(clash)} of the files this import writes are "
                              f"there already ({clash[0].name}, ...); {refuse}")
        # whole or nothing: move the validated files into place
        asset_dir.mkdir(exist_ok=True)
        written = []
        for p in sorted(own):
            shutil.move(str(p), asset_dir / p.name)
            written.append(asset_dir / p.name)
        stage_written = []
        for rel in stage_writes:
            (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(tmp / rel), out_dir / rel)
            stage_written.append(out_dir / rel)
        text = (tmp / f"{name}.xml").read_text()
        if bundled:  # the bundled stage declares its arm itself
            text = text.replace("\n".join(stage.head), f'  <include file="{stage.name}"/>')
        xml_path.write_text(text)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()  # nothing written: leave no empty folder behind
        raise
    shutil.rmtree(tmp, ignore_errors=True)
    for n in notes:
        log.info("%s: %s", name, n)
    return ImportResult(xml_path, written, s, qa, qb, notes, stage_written)


def _stage_writes(stage, out_dir: Path, overwrite: bool) -> list[str]:
    """The stage files (paths relative to ``out_dir``) to write there: those missing, and on
    ``overwrite`` those that differ. Raises where a file differs without ``overwrite``, or where
    the stage file itself differs and was not written by the import."""
    missing, differ = [], []
    for rel, data in stage.files.items():
        dest = out_dir / rel
        if not dest.exists():
            missing.append(rel)
        elif not dest.is_file() or dest.read_bytes() != data:
            differ.append(rel)
    if not differ:
        return missing
    what = (f"{len(differ)} of the stage's files this import writes beside the scene (the "
            f"stage, its assets and the arm) differ from the harness's in {out_dir}: "
            f"{', '.join(differ[:3])}{', ...' if len(differ) > 3 else ''}; the folder's other "
            f"scenes use them")
    if stage.name in differ and not is_stage_copy(out_dir / stage.name):
        raise AuthorError(f"{what}, and {stage.name} there was not written by sim.author (a "
                          f"stage of your own?); fix: import into another folder (--out)")
    if not overwrite:
        raise AuthorError(f"{what} (written by another version of the harness?); fix: another "
                          f"--out, or --overwrite to replace them with the harness's current "
                          f"ones (the folder's other scenes then use those)")
    return missing + differ


def _validate(path: Path, qa: dict, qb: dict) -> set[str]:
    """Load the scene, step it in A and B; returns the joints that creep (raises on anything
    else)."""
    try:
        scene = load_scene(path)
    except SceneError as err:
        raise AuthorError(f"the imported scene does not validate (report this bug): "
                          f"{err}") from err
    creeping = set()
    for c in ("a", "b"):
        warnings = physics_warnings(scene, HOLD_SECONDS, c)
        if warnings:
            raise AuthorError(f"{path.name}: MuJoCo warnings in {HOLD_SECONDS:g} s of physics "
                              f"in configuration {c.upper()}: {warnings}; fix: check the "
                              f"source's collision geometry")
        data = scene.make_data(c)
        mujoco.mj_step(scene.model, data, nstep=int(round(HOLD_SECONDS /
                                                          scene.model.opt.timestep)))
        for j in scene.joints:
            if abs(data.qpos[j.qpos_adr] - j.value(c)) >= 0.5 * HOLD_TOLERANCE[j.type]:
                creeping.add(j.name)
    return creeping
