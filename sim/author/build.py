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
8. write ``OUT/NAME.xml`` and ``OUT/assets/NAME_*``, validate the scene
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

from sim.assets import OBJECT_TEXEL, SEED, texture_mesh
from sim.author.source import (
    AuthorError,
    Primitive,
    SourceObject,
    pose,
    rotation_about,
    transform_points,
)

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
#: A joint's friction loss is at least this many times the largest gravity load it carries in
#: A or B (MuJoCo's friction is soft: with the stiff friction solver settings below, 1.5 times
#: the load holds the bundled truck's bed), and raised by HOLD_FRICTION_GROWTH per failed check.
FRICTION_OVER_LOAD = 1.5
HOLD_FRICTION_GROWTH = 2.0
HOLD_TRIES = 4
#: Friction loss without load, relative to the child subtree's weight (N) times its reach (m,
#: revolute) or its weight (prismatic): the bundled cabinet's door (0.38 kg, 30 cm) and drawer
#: (0.52 kg) have 0.5 N m and 0.5 N; these factors give about that for such parts.
FRICTION_PER_WEIGHT = {"revolute": 0.3, "prismatic": 0.1}
#: Damping (per unit of friction loss, s): the bundled cabinet's 2 over 0.5.
DAMPING_PER_FRICTION = 4.0
ARMATURE = 0.01
#: MuJoCo's friction loss made stiff, as truck.xml does for its loaded hinge.
SOLREF_FRICTION = "0.004 1"
SOLIMP_FRICTION = "0.99 0.999 0.001"
#: A collision hull thinner than this (m) is replaced by a box around the piece at least this
#: thick: qhull cannot hull a flat piece, and MuJoCo refuses a mesh without volume.
MIN_THICKNESS = 0.002
#: Continuous joints get this range (rad): a full turn either way.
CONTINUOUS_RANGE = (-math.pi, math.pi)
#: Up axes the source may have (``--up``): the rotation taking it to +z.
UP_AXES = {"+z": np.eye(3), "-z": np.diag([1.0, -1.0, -1.0]),
           "+y": rotation_about([1.0, 0.0, 0.0], math.pi / 2),
           "-y": rotation_about([1.0, 0.0, 0.0], -math.pi / 2),
           "+x": rotation_about([0.0, 1.0, 0.0], -math.pi / 2),
           "-x": rotation_about([0.0, 1.0, 0.0], math.pi / 2)}


#: How the parts are textured (:attr:`ImportConfig.texture`).
TEXTURES = ("generated", "source")
#: Collision shapes of meshes (:attr:`ImportConfig.collision`).
COLLISIONS = ("box", "hull")


@dataclass(frozen=True)
class ImportConfig:
    """How an object is imported (the options of ``python -m sim.author import``)."""

    name: str | None = None
    """scene name: the file stem and the prefix of its assets (default: from the source file,
    its folder's name for a PartNet-Mobility ``mobility.urdf``)"""
    size: float = 0.25
    """largest extent (m) of the object at configuration A after scaling (the bundled objects
    are 16 - 32 cm: the capture rings and the table fit that)"""
    scale: float | None = None
    """a fixed scale factor instead of ``size`` (1: keep a metric source's size)"""
    up: str = "+z"
    """the source's up axis (``+z``, ``+y``, ...), turned to the world's +z"""
    body: str | None = None
    """MJCF only: the object's root body (default: the only top-level body with geoms)"""
    config_a: Mapping[str, float] = field(default_factory=dict)
    """joint values of configuration A (rad, or m after scaling); others at 0 or their limit"""
    config_b: Mapping[str, float] = field(default_factory=dict)
    """joint values of configuration B; others move by the default motion"""
    revolute_motion: float = math.radians(30.0)
    """default motion A -> B of a revolute joint (rad): the method sees 25 - 35 deg well"""
    prismatic_motion: float = 0.10
    """default motion A -> B of a prismatic joint (m): the method sees 8 - 12 cm well"""
    density: float = 500.0
    """density (kg/m^3) of the collision shapes, which carry the mass (a hollow toy or wooden
    furniture: the bundled objects use 400 - 600)"""
    texel: float = OBJECT_TEXEL
    """wanted texel size (m) of the generated textures"""
    seed: int = SEED
    """master seed of the textures (each part's seed derives from it and the part's name)"""
    collision: str = "box"
    """``box``: each collision mesh becomes the oriented box around it (the simple primitives
    the bundled scenes use; the arm's default grasp points lie on box and cylinder faces);
    ``hull``: its convex hull (closer to a round shape; no default grasp points on it)"""
    texture: str = "generated"
    """``generated``: every link's meshes UV-unwrapped and given a new non-repeating texture
    (what SfM needs); ``source``: keep each visual mesh's own UVs and texture image (a scanned
    or photo-textured model), refused for a mesh that has none"""
    arm: str = "puma560"
    """the arm on the stage: ``puma560`` or ``panda``"""
    overwrite: bool = False
    """replace files of an earlier import of the same name in the output folder"""

    def __post_init__(self):
        if self.up not in UP_AXES:
            raise ValueError(f"up must be one of {sorted(UP_AXES)}, got {self.up!r}")
        if not self.size > 0 or (self.scale is not None and not self.scale > 0):
            raise ValueError(f"size and scale must be positive, got {self.size}, {self.scale}")
        if not self.density > 0 or not self.texel > 0:
            raise ValueError("density and texel must be positive")
        if self.collision not in COLLISIONS:
            raise ValueError(f"collision must be one of {COLLISIONS}, got {self.collision!r}")
        if self.texture not in TEXTURES:
            raise ValueError(f"texture must be one of {TEXTURES}, got {self.texture!r}")


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


# ------------------------------------------------------------------------------- reading


def read_source(path: Path, body: str | None = None) -> SourceObject:
    """Read a URDF or an MJCF file (told apart by the root element)."""
    from sim.author.mjcf import read_mjcf
    from sim.author.urdf import read_urdf

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


def sanitize(name: str) -> str:
    """A name safe in MJCF and file names: letters, digits, ``_`` and ``-``."""
    out = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_")
    if not out:
        return "part"
    return out if out[0].isalpha() or out[0] == "_" else f"obj_{out}"


# ------------------------------------------------------------------------------- choices


def _range(j, scale: float = 1.0) -> np.ndarray:
    if j.range is None:
        return np.array(CONTINUOUS_RANGE)
    return j.range * (scale if j.type == "prismatic" else 1.0)


def default_a(j, scale: float = 1.0) -> float:
    """Configuration A of a joint: 0 if inside its range, else the limit nearest 0."""
    lo, hi = _range(j, scale)
    return float(min(max(0.0, lo), hi))


def default_b(j, a: float, motion: float, scale: float, notes: list[str]) -> float:
    """Configuration B of a joint: ``a`` moved by ``motion`` where the range has room (forward
    first), else as far as the range allows (noted)."""
    lo, hi = _range(j, scale)
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
        lo, hi = _range(j, scale)
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


# ------------------------------------------------------------------------------- geometry


def _hull(v: np.ndarray, name: str):
    """Convex hull (vertices, faces) of points, or None where it is flat or fails."""
    import trimesh

    extent = np.ptp(v, axis=0)
    if len(v) < 4 or np.sort(extent)[0] < MIN_THICKNESS:
        return None
    try:
        hull = trimesh.Trimesh(v, process=False).convex_hull
    except Exception as err:  # qhull's errors come in several types
        log.debug("%s: no hull (%s)", name, err)
        return None
    # mean thickness of the hull: twice its volume over its area (a slab: its thickness)
    if hull.volume <= 0 or 2.0 * hull.volume / hull.area < MIN_THICKNESS:
        return None
    return np.asarray(hull.vertices, float), np.asarray(hull.faces, np.int64)


def _box_around(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Oriented box around points: (half sizes (3,), T_frame_box (4, 4)), at least
    MIN_THICKNESS thick."""
    import trimesh

    try:
        T, extents = trimesh.bounds.oriented_bounds(v)
        T_frame_box = np.linalg.inv(T)
    except Exception:  # degenerate input: the axis-aligned box
        lo, hi = v.min(0), v.max(0)
        T_frame_box, extents = pose(t=(lo + hi) / 2), hi - lo
    return np.maximum(np.asarray(extents, float), MIN_THICKNESS) / 2, T_frame_box


def _quat(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).reshape(-1))
    return q


def _f(*values: float) -> str:
    return " ".join(f"{v:.6g}" if abs(v) >= 1e-9 else "0" for v in values)


def _write_plain_obj(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    lines = [f"# {path.name}: generated by sim.author, do not edit"]
    lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
    lines += [f"f {a} {b} {c}" for a, b, c in f + 1]
    path.write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------- the import


def import_object(source: str | Path, out_dir: str | Path,
                  config: ImportConfig | None = None) -> ImportResult:
    """Import an articulated object from a URDF or an MJCF file as a scene of the harness.

    Parameters
    ----------
    source : path
        ``mobility.urdf`` (PartNet-Mobility layout: OBJ meshes per part), any URDF, or an MJCF.
    out_dir : path
        Folder of the scene: ``OUT/NAME.xml`` and ``OUT/assets/NAME_*`` (created). Anywhere on
        disk: the scene includes the bundled stage by its absolute path.
    config : ImportConfig, optional

    Returns
    -------
    ImportResult

    Raises
    ------
    AuthorError
        The source cannot be read or imported, a configuration is wrong, the object overhangs
        the table, the scene does not validate or a configuration does not hold; or the output
        files exist (pass ``overwrite``). Nothing is written then.
    """
    from sim.scene import BUNDLED_SCENES_DIR

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
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=out_dir))
    try:
        writer = _SceneWriter(obj, name, config, s, U, t, tmp, notes)
        writer.build()
        stage = str(stage_of(config.arm))  # by its absolute path while in the temporary folder
        friction = writer.initial_friction(stage, qa, qb)
        for attempt in range(HOLD_TRIES + 1):
            writer.write(stage, qa, qb, friction)
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
        clash = [asset_dir / p.name for p in (tmp / "assets").iterdir()
                 if (asset_dir / p.name).exists()]
        if clash and not config.overwrite:
            raise AuthorError(f"{asset_dir}: {len(clash)} of the files this import writes are "
                              f"there already ({clash[0].name}, ...); {refuse}")
        # whole or nothing: move the validated files into place
        asset_dir.mkdir(exist_ok=True)
        written = []
        for p in sorted((tmp / "assets").iterdir()):
            shutil.move(str(p), asset_dir / p.name)
            written.append(asset_dir / p.name)
        text = (tmp / f"{name}.xml").read_text()
        if out_dir == BUNDLED_SCENES_DIR.resolve():  # beside the stage: include it by name
            text = text.replace(f'<include file="{stage}"/>',
                                f'<include file="{Path(stage).name}"/>')
        xml_path.write_text(text)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()  # nothing written: leave no empty folder behind
        raise
    shutil.rmtree(tmp, ignore_errors=True)
    for n in notes:
        log.info("%s: %s", name, n)
    return ImportResult(xml_path, written, s, qa, qb, notes)


def stage_of(arm: str) -> Path:
    """The bundled stage carrying ``arm``."""
    from sim.scene import stage_file

    return stage_file(arm)


def _validate(path: Path, qa: dict, qb: dict) -> set[str]:
    """Load the scene, step it in A and B; returns the joints that creep (raises on anything
    else)."""
    from sim.scene import SceneError, load_scene, physics_warnings

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


class _SceneWriter:
    """Assets and XML of one imported scene, written into a folder."""

    def __init__(self, obj: SourceObject, name: str, config: ImportConfig, s: float,
                 U: np.ndarray, t: np.ndarray, folder: Path, notes: list[str]):
        self.obj, self.name, self.config, self.s, self.folder = obj, name, config, s, folder
        self.U, self.t, self.notes = U, t, notes
        self.T_object_root = pose(U, t)  # for frames; geometry also scales by s
        self.body_name = {obj.root: "object"}
        used = {"object"}
        for j in obj.joints:
            n = sanitize(j.child)
            while n in used:
                n += "_"
            used.add(n)
            self.body_name[j.child] = n
        self.joint_name = {j.name: sanitize(j.name) for j in obj.joints}
        if len(set(self.joint_name.values())) != len(self.joint_name):
            raise AuthorError(f"{obj.path}: joint names {sorted(self.joint_name)} are not "
                              f"distinct once made MJCF-safe; fix: rename them")
        self.assets: list[str] = []
        self.geoms: dict[str, list[str]] = {}

    # geometry in each link's own (scaled) frame; the root link's frame is the object's
    def _to_body(self, link: str, v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, float) * self.s
        if link == self.obj.root:
            return v @ self.U.T + self.t
        return v

    def _T_body(self, link: str, T: np.ndarray) -> np.ndarray:
        T = T.copy()
        T[:3, 3] *= self.s
        return self.T_object_root @ T if link == self.obj.root else T

    def build(self) -> None:
        """Textured visual meshes and collision shapes of every link (into ``assets/``)."""
        adir = self.folder / "assets"
        adir.mkdir()
        density = self.config.density
        for link_name, link in self.obj.links.items():
            body = self.body_name[link_name]
            geoms = []
            if link.visuals and self.config.texture == "source":
                for i, m in enumerate(link.visuals):
                    part = f"{self.name}_{body}_{i}" if len(link.visuals) > 1 else \
                        f"{self.name}_{body}"
                    self._source_textured(adir, part, link_name, m)
                    geoms.append(f'<geom name="{part}_visual" class="visual" mesh="{part}" '
                                 f'material="{part}"/>')
            elif link.visuals:
                v = np.concatenate([self._to_body(link_name, m.vertices) for m in link.visuals])
                offsets = np.cumsum([0] + [len(m.vertices) for m in link.visuals])
                f = np.concatenate([m.faces + o for m, o in zip(link.visuals, offsets,
                                                                strict=False)])
                part = f"{self.name}_{body}"
                tp = texture_mesh(v, f, adir, part, texel=self.config.texel,
                                  seed=self.config.seed, generator="sim.author")
                self.notes.append(f"link {link_name!r} -> body {body!r}: {len(f)} triangles, "
                                  f"texture {tp.width}x{tp.height} at "
                                  f"{tp.texel * 1000:.2f} mm per texel")
                self.assets += [f'<texture name="{part}" type="2d" file="assets/{part}.png"/>',
                                f'<material name="{part}" texture="{part}" specular="0.1" '
                                f'shininess="0.1"/>',
                                f'<mesh name="{part}" file="assets/{part}.obj" '
                                f'inertia="shell"/>']
                geoms.append(f'<geom name="{part}_visual" class="visual" mesh="{part}" '
                             f'material="{part}"/>')
            pieces = link.collisions or link.visuals
            k = 0
            for piece in pieces:
                if isinstance(piece, Primitive):
                    T = self._T_body(link_name, piece.T_link_geom)
                    size = piece.size * self.s
                    geoms.append(self._primitive(body, k, piece.type, size, T, density))
                    k += 1
                    continue
                v = self._to_body(link_name, piece.vertices)
                hull = _hull(v, piece.name) if self.config.collision == "hull" else None
                if hull is None:
                    half, T = _box_around(v)
                    geoms.append(self._primitive(body, k, "box", half, T, density))
                else:
                    mesh = f"{self.name}_{body}_hull{k}"
                    _write_plain_obj(adir / f"{mesh}.obj", *hull)
                    self.assets.append(f'<mesh name="{mesh}" file="assets/{mesh}.obj"/>')
                    geoms.append(f'<geom name="{mesh}" class="collision" type="mesh" '
                                 f'mesh="{mesh}" density="{density:g}"/>')
                k += 1
            if k == 0:
                raise AuthorError(f"{self.obj.path}: link {link_name!r} has neither visual nor "
                                  f"collision geometry; fix: give it a mesh")
            self.geoms[link_name] = geoms

    def _source_textured(self, adir: Path, part: str, link: str, m) -> None:
        """One visual mesh with its own UVs and image (``--texture source``)."""
        from sim.assets import write_png

        if m.uv is None or m.image is None:
            raise AuthorError(f"{self.obj.path}: the visual mesh {m.name!r} of link {link!r} "
                              f"has no texture of its own (UVs and an image); fix: import with "
                              f"--texture generated (the default), which textures every part")
        v = self._to_body(link, m.vertices)
        n = np.cross(v[m.faces[:, 1]] - v[m.faces[:, 0]], v[m.faces[:, 2]] - v[m.faces[:, 0]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        lines = [f"# {part}.obj: generated by sim.author (the source's own UVs), do not edit"]
        lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
        lines += [f"vt {a:.6f} {b:.6f}" for a, b in m.uv.reshape(-1, 2)]
        lines += [f"vn {a:.6f} {b:.6f} {c:.6f}" for a, b, c in n]
        lines += ["f " + " ".join(f"{vi + 1}/{3 * k + c + 1}/{k + 1}" for c, vi in enumerate(t))
                  for k, t in enumerate(m.faces)]
        (adir / f"{part}.obj").write_text("\n".join(lines) + "\n")
        write_png(adir / f"{part}.png", np.ascontiguousarray(m.image[..., :3]))
        self.assets += [f'<texture name="{part}" type="2d" file="assets/{part}.png"/>',
                        f'<material name="{part}" texture="{part}" specular="0.1" '
                        f'shininess="0.1"/>',
                        f'<mesh name="{part}" file="assets/{part}.obj" inertia="shell"/>']
        self.notes.append(f"link {link!r}: {m.name} keeps its own texture "
                          f"{m.image.shape[1]}x{m.image.shape[0]}")

    def _primitive(self, body: str, k: int, kind: str, size, T, density: float) -> str:
        q = _quat(T[:3, :3])
        return (f'<geom name="{self.name}_{body}_collision{k}" class="collision" type="{kind}" '
                f'size="{_f(*size)}" pos="{_f(*T[:3, 3])}" quat="{_f(*q)}" '
                f'density="{density:g}"/>')

    def initial_friction(self, stage: str, qa: dict, qb: dict) -> dict[str, float]:
        """Friction loss per joint: the baseline of its child's weight, or more than the
        gravity load it carries in A and B (from a provisional compile)."""
        friction = {j.name: 0.0 for j in self.obj.joints}
        self.write(stage, qa, qb, friction)
        model = mujoco.MjModel.from_xml_path(str(self.folder / f"{self.name}.xml"))
        data = mujoco.MjData(model)
        out = {}
        for j in self.obj.joints:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, self.joint_name[j.name])
            dof = int(model.jnt_dofadr[jid])
            body = int(model.jnt_bodyid[jid])
            weight = float(model.body_subtreemass[body]) * float(np.linalg.norm(model.opt.gravity))
            load = 0.0
            for q in (qa, qb):
                for other in self.obj.joints:
                    oid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                            self.joint_name[other.name])
                    data.qpos[model.jnt_qposadr[oid]] = q[other.name]
                data.qvel[:] = 0
                mujoco.mj_forward(model, data)
                load = max(load, abs(float(data.qfrc_bias[dof])))
            reach = self.config.size if j.type == "revolute" else 1.0
            base = FRICTION_PER_WEIGHT[j.type] * weight * reach
            out[j.name] = max(base, FRICTION_OVER_LOAD * load)
        return out

    def write(self, stage: str, qa: dict, qb: dict, friction: dict[str, float]) -> None:
        """The scene file (assets written by :meth:`build`)."""
        obj, names = self.obj, self.body_name
        children: dict[str, list] = {}
        for j in obj.joints:
            children.setdefault(j.parent, []).append(j)
        lines = [f"<!-- {self.name}: imported from {obj.path} by `python -m sim.author import`",
                 f"     (scale {self.s:.6g}: source units to metres). Conventions: "
                 f"scenes/README.md."]
        lines += [f"     - {n}" for n in self.notes]
        lines += ["-->", f'<mujoco model="{self.name}">', f'  <include file="{stage}"/>', "",
                  "  <asset>"]
        lines += [f"    {a}" for a in self.assets]
        lines += ["  </asset>", "", "  <worldbody>"]

        def body(link: str, joint, T: np.ndarray, indent: str):
            b = names[link]
            if joint is None:
                lines.append(f'{indent}<body name="object" pos="0 0 0.45">')
            else:
                lines.append(f'{indent}<body name="{b}" pos="{_f(*T[:3, 3])}" '
                             f'quat="{_f(*_quat(T[:3, :3]))}">')
                rng = _range(joint, self.s)
                fl = friction[joint.name]
                kind = "hinge" if joint.type == "revolute" else "slide"
                lines.append(
                    f'{indent}  <joint name="{self.joint_name[joint.name]}" type="{kind}" '
                    f'pos="{_f(*(joint.anchor * self.s))}" axis="{_f(*joint.axis)}" '
                    f'range="{_f(*rng)}" damping="{DAMPING_PER_FRICTION * fl:.4g}" '
                    f'frictionloss="{fl:.4g}" armature="{ARMATURE:g}" '
                    f'solreffriction="{SOLREF_FRICTION}" solimpfriction="{SOLIMP_FRICTION}"/>')
            lines.extend(f"{indent}  {g}" for g in self.geoms[link])
            for cj in children.get(link, []):
                body(cj.child, cj, self._T_body(link, cj.T_parent_child), indent + "  ")
            lines.append(f"{indent}</body>")

        body(obj.root, None, np.eye(4), "    ")
        lines += ["  </worldbody>", ""]
        bodies = [names[n] for n in obj.links]
        if len(bodies) > 1:
            lines += ["  <!-- The joints alone guide the links: no contacts between them. -->",
                      "  <contact>"]
            lines += [f'    <exclude body1="{a}" body2="{b}"/>'
                      for i, a in enumerate(bodies) for b in bodies[i + 1:]]
            lines += ["  </contact>", ""]
        lines += ["  <!-- Configurations A and B (radians for hinges, metres for slides). -->",
                  "  <custom>"]
        for c, q in (("a", qa), ("b", qb)):
            lines += [f'    <numeric name="config_{c}:{self.joint_name[j.name]}" '
                      f'data="{q[j.name]:.6g}"/>' for j in obj.joints]
        lines += ["  </custom>", "</mujoco>", ""]
        (self.folder / f"{self.name}.xml").write_text("\n".join(lines))
