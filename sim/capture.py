"""Eye-in-hand capture: the arm photographs the object from all sides.

``python -m sim.capture SCENE --config a|b --out DIR [--views N] [--seed S]`` writes one image set::

    DIR/images/000.png ...        what the wrist camera saw (RGB)
    DIR/cameras.json              intrinsics K, size, per image the arm's joint angles, the
                                  camera and the flange pose from the arm's forward kinematics
                                  (what a real robot knows); this and images/ are what artrecon
                                  reads
    DIR/capture.json              the plan: views planned, captured, unreachable and why
    DIR/ground_truth/             scoring only, never read by artrecon:
        poses.json                true camera poses (MuJoCo), FK error, object joint values, object
                                  link poses, label legend, depth scale
        depth/000.png             uint16 depth along the optical axis, 1 unit = 0.1 mm, 0 = none
        labels/000.png            uint8 label: object link index, 253 arm, 254 stage, 255 nothing

The views lie on rings around the object, each ring's distance and elevation chosen so that the
arm reaches every view of it without a collision (:func:`sim.views.plan_capture`); the arm reaches
each by inverse kinematics and MuJoCo moves it there with its position servos (physics, joint-space
interpolation), then the image is rendered with pyrender (:mod:`sim.render`) at the wrist camera's
true pose. The object is at rest while it is photographed: its joints are held at the
configuration's values by stiff joint equalities (:meth:`sim.scene.Scene.with_joint_holds`; joint
friction alone lets a loaded hinge creep over the minutes of a capture), and every physics step
is checked for contacts of the arm, so that an arm that touches the object (or the table, or
itself) is an error, not a hold that quietly absorbs it. The set is written to a temporary folder
beside DIR and renamed, so DIR is whole or absent.
"""

from __future__ import annotations

import functools
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import mujoco
import numpy as np
from PIL import Image
from tqdm import tqdm

from artrecon.files import check_output_dir, check_output_path
from artrecon.geometry import rotation_angle
from sim import render, robot, views
from sim.camera import convert_camera_pose, mujoco_camera_intrinsics

log = logging.getLogger(__name__)

CONFIGS = ("a", "b")

#: Fewest images a set may have: fewer cannot give a reconstruction from all sides.
MIN_CAPTURED_VIEWS = 8

#: Peak joint-space speed (rad/s) of the commanded motion between views (a minimum-jerk profile
#: along the straight joint-space line, with computed-torque feed-forward: see :class:`_Arm`).
MOVE_SPEED = 1.0
#: The arm has settled when its joint speeds are below this (rad/s) ...
SETTLE_SPEED = 1e-3
#: ... or after this much simulated time (s), whichever is first.
SETTLE_MAX_TIME = 2.0
#: The object may not move while the arm works around it: its joints must stay within this of
#: the configuration (rad or m); 0.1 mrad / 0.1 mm is below anything a reconstruction resolves.
#: The joint holds keep loaded hinges within 1e-5 of it (sim.scene.HOLD_SOLREF).
OBJECT_DRIFT_TOL = 1e-4

#: Label codes in ground_truth/labels/*.png.
LABEL_PNG_ARM = 253
LABEL_PNG_STAGE = 254
LABEL_PNG_BACKGROUND = 255
#: Renderer labels of the arm (rail carriage and everything on it) and of the rest of the stage.
LABEL_ARM = -2
LABEL_STAGE = -3
#: Depth PNG unit (m): 0.1 mm, far below the 1 mm scoring tolerance; range up to 6.55 m.
DEPTH_PNG_SCALE = 1e-4


class CaptureError(RuntimeError):
    """The capture cannot produce a usable image set (too few reachable views, the arm touched
    something on its way, the object moved)."""


@dataclass
class CaptureResult:
    """What :func:`capture` wrote."""

    out_dir: Path
    """the image set folder"""
    n_planned: int
    """views planned"""
    n_captured: int
    """images written"""
    unreachable: list[dict] = field(default_factory=list)
    """views the arm could not reach: ring, azimuth/elevation (deg), reason"""
    free_camera: list[int] = field(default_factory=list)
    """image indices taken by a free camera (only with ``free_camera_fallback``)"""
    max_fk_position_error: float = 0.0
    """largest distance (m) between the FK camera pose and MuJoCo's camera"""
    max_fk_rotation_error: float = 0.0
    """largest angle (rad) between them"""
    plan_cached: bool = False
    """the view plan was read from the plan cache (no IK was solved)"""
    timings: dict = field(default_factory=dict)
    """seconds spent planning, moving, rendering (wall, ``*_s``) and CPU seconds (``*_cpu_s``,
    ``cpu_s`` the whole capture's, all threads); not written to disk"""


# ------------------------------------------------------------------------------------ scene access
def _load(scene):
    """A :class:`sim.scene.Scene` from a bundled name, an MJCF path or a loaded scene."""
    from sim.scene import Scene, load_scene

    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    raise TypeError(f"scene must be a name, a path or a sim.scene.Scene, got {type(scene)}")


def _joint_values(sc, data) -> dict[str, float]:
    return {j.name: float(data.qpos[j.qpos_adr]) for j in sc.joints}


def _geom_labels(model: mujoco.MjModel, sc, arm_root: int) -> np.ndarray:
    """Renderer label of every geom: object link index, LABEL_ARM or LABEL_STAGE."""
    link_of = {b: i for i, li in enumerate(sc.links) for b in li.body_ids}
    labels = np.full(model.ngeom, LABEL_STAGE, dtype=np.int64)
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b in link_of:
            labels[g] = link_of[b]
            continue
        c = b
        while c > 0 and c != arm_root:
            c = int(model.body_parentid[c])
        if c == arm_root and arm_root > 0:
            labels[g] = LABEL_ARM
    return labels


def _labels_png(labels: np.ndarray) -> np.ndarray:
    out = np.full(labels.shape, LABEL_PNG_BACKGROUND, dtype=np.uint8)
    links = labels >= 0
    if np.any(labels[links] >= LABEL_PNG_ARM):
        raise CaptureError(f"more than {LABEL_PNG_ARM} object links cannot be stored in 8 bits")
    out[links] = labels[links]
    out[labels == LABEL_ARM] = LABEL_PNG_ARM
    out[labels == LABEL_STAGE] = LABEL_PNG_STAGE
    return out


def read_labels_png(path) -> np.ndarray:
    """Labels : (h, w) int from a ground-truth label PNG: the object link's index, or
    LABEL_ARM / LABEL_STAGE / LABEL_BACKGROUND (all < 0) for anything else."""
    png = np.asarray(Image.open(path), dtype=np.int64)
    out = png.copy()
    out[png == LABEL_PNG_ARM] = LABEL_ARM
    out[png == LABEL_PNG_STAGE] = LABEL_STAGE
    out[png == LABEL_PNG_BACKGROUND] = render.LABEL_BACKGROUND
    return out


def _depth_png(depth: np.ndarray) -> np.ndarray:
    units = np.round(np.asarray(depth, dtype=np.float64) / DEPTH_PNG_SCALE)
    units[(units <= 0) | (units > 65535)] = 0
    return units.astype(np.uint16)


#: How the PNGs are encoded (OpenCV's libpng, zlib level 1; lossless: the pixels are the same
#: whatever the setting). One row filter (Sub) instead of libpng's per-row trial of all five, and
#: run-length matching for the colour and label images: at 640 x 480 a colour image takes
#: 11.5 ms of CPU and 291 kB, where PIL's level 1 (this module's writer before) took 22.5 ms and
#: 320 kB; a depth image 3.5 ms (PIL 6.7), a label image 0.8 ms (1.3).
PNG_PARAMS = {
    "colour": (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
               cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE),
    "depth": (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
              cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_DEFAULT),
    "labels": (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
               cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE),
}


def _png_bytes(array: np.ndarray, kind: str) -> bytes:
    """A PNG file's bytes of an (h, w, 3) uint8 RGB image (``kind`` "colour") or an (h, w)
    uint16 / uint8 image ("depth", "labels")."""
    if array.ndim == 3:
        array = np.ascontiguousarray(array[:, :, ::-1])  # OpenCV takes BGR
    ok, buf = cv2.imencode(".png", array, list(PNG_PARAMS[kind]))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {kind} PNG of shape {array.shape}")
    return buf.tobytes()


def _write_pngs(items) -> float:
    """Write ``(array, path, kind)`` triples as PNG files (kind: a key of :data:`PNG_PARAMS`);
    returns the CPU seconds this thread spent on it."""
    t0 = time.thread_time()
    for array, path, kind in items:
        Path(path).write_bytes(_png_bytes(array, kind))
    return time.thread_time() - t0


def read_depth_png(path) -> np.ndarray:
    """Depth (m) : (h, w) float from a ground-truth depth PNG (0 where no surface)."""
    return np.asarray(Image.open(path), dtype=np.float64) * DEPTH_PNG_SCALE


def _as_list(T) -> list:
    return [[float(x) for x in row] for row in np.asarray(T)]


# ------------------------------------------------------------------------------------ arm motion
#: Peak of the minimum-jerk profile's speed, in units of (distance / duration).
MIN_JERK_PEAK_SPEED = 1.875


def min_jerk(tau: float) -> tuple[float, float, float]:
    """Minimum-jerk time scaling at ``tau`` in [0, 1]: the share of the way ``s`` and its first
    and second derivatives with respect to ``tau`` (zero speed and acceleration at both ends;
    peak speed 1.875 at 0.5)."""
    t = min(max(float(tau), 0.0), 1.0)
    return (t ** 3 * (10.0 - 15.0 * t + 6.0 * t * t),
            30.0 * t * t * (1.0 - 2.0 * t + t * t),
            60.0 * t * (1.0 - 3.0 * t + 2.0 * t * t))


def servo_gains(model: mujoco.MjModel, actuators) -> tuple[np.ndarray, np.ndarray]:
    """``(kp, kv)`` : two (n,) float of position servos (``gainprm[0] = kp``,
    ``biasprm = (0, -kp, -kv)``); raises ValueError for any other kind of actuator."""
    actuators = np.asarray(actuators, int)
    kp = model.actuator_gainprm[actuators, 0].copy()
    kv = -model.actuator_biasprm[actuators, 2]
    if np.any(kp <= 0) or np.any(np.abs(model.actuator_biasprm[actuators, 1] + kp) > 1e-9 * kp):
        names = [model.actuator(int(a)).name for a in actuators]
        raise ValueError(f"the arm's actuators {names} must be position servos (kp > 0, bias "
                         "-kp q - kv qdot); check the robot's <position> actuators")
    return kp, kv


def _as_slice(index: np.ndarray):
    """``index`` as a slice when it is a contiguous ascending run (numpy then takes a view),
    else unchanged."""
    index = np.asarray(index)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class _Arm:
    """Moves the arm in MuJoCo with its position servos and watches what it touches.

    A move follows the straight joint-space line that the view planner checked
    (:func:`sim.views.check_paths`), on a minimum-jerk profile. A position servo (force
    ``kp (ctrl - q) - kv qdot``) fed only the reference lags it by ``(kv + damping) / kp`` times
    the speed -- the rail's servo (1 Hz, for 110 kg m^2) by 0.3 s, the arm's by 0.04-0.08 s -- so
    the rail trails the wrist and the executed path leaves the checked line (by 0.3 rad on the
    rail at 1 rad/s, measured). The command therefore carries the torque the reference motion
    needs (inverse dynamics at the reference position, speed and acceleration: inertia, the
    coupling of the arm's motion into the rail, gravity, damping) plus the servo's own damping:
    computed-torque feed-forward through the position servo,
    ``ctrl = q_ref + (tau_ref + kv v_ref) / kp``. The arm also holds its targets without sag.
    :attr:`max_path_deviation` records how far each joint strayed from the line.
    """

    def __init__(self, model, data, kin):
        self.model, self.data, self.kin = model, data, kin
        self.qidx = robot.qpos_indices(model, kin)
        self.vidx = np.array([model.jnt_dofadr[mujoco.mj_name2id(
            model, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in kin.joint_names])
        self.aidx = robot.actuator_indices(model, kin)
        self.links = views.arm_link_bodies(model, kin)
        #: geoms of the arm links, to test every physics step's contacts cheaply
        self.arm_geom = np.isin(model.geom_bodyid, sorted(self.links))
        self.kp, self.kv = servo_gains(model, self.aidx)
        #: joints whose actuators already carry the gravity compensation of their bodies
        #: (MuJoCo's actuatorgravcomp): that share of the inverse dynamics is not the servo's
        self.actuator_gravcomp = model.jnt_actgravcomp[[
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in kin.joint_names]]
        #: scratch data for the inverse dynamics of the reference
        self._inverse = mujoco.MjData(model)
        # views of the arrays touched at every physics step, and the joints' addresses as
        # slices where they are contiguous (a move is ~250 steps; numpy's per-call overhead on
        # these 6-vectors was most of its CPU besides mj_step and mj_inverse)
        self._iq, self._iv, self._ia = (_as_slice(i) for i in (self.qidx, self.vidx, self.aidx))
        self._qpos, self._qvel, self._ctrl = data.qpos, data.qvel, data.ctrl
        inv = self._inverse
        self._inv_qpos, self._inv_qvel, self._inv_qacc = inv.qpos, inv.qvel, inv.qacc
        self._inv_frc, self._inv_grav = inv.qfrc_inverse, inv.qfrc_gravcomp
        #: the joint values the arm was last sent to (None: wherever it stands)
        self.target: np.ndarray | None = None
        #: largest distance (rad or m) of each joint from the planned line, over all moves
        self.max_path_deviation = np.zeros(len(self.qidx))

    def command(self, q_ref, v_ref=None, a_ref=None) -> np.ndarray:
        """Servo targets that make the arm follow ``q_ref`` with speed ``v_ref`` and
        acceleration ``a_ref`` (default 0: hold ``q_ref``) : (n,) float."""
        iv = self._iv
        v_ref = np.zeros(len(self.qidx)) if v_ref is None else v_ref
        np.copyto(self._inv_qpos, self._qpos)
        self._inv_qpos[self._iq] = q_ref
        self._inv_qvel.fill(0.0)
        self._inv_qvel[iv] = v_ref
        self._inv_qacc.fill(0.0)
        if a_ref is not None:
            self._inv_qacc[iv] = a_ref
        mujoco.mj_inverse(self.model, self._inverse)
        tau = self._inv_frc[iv] - self.actuator_gravcomp * self._inv_grav[iv]
        return q_ref + (tau + self.kv * v_ref) / self.kp

    def place(self, q):
        """Start the arm at ``q`` (the robot's initial pose), at rest and held there."""
        q = np.asarray(q, dtype=float)
        self.data.qpos[self.qidx] = q
        self.data.qvel[:] = 0.0
        self.target = q.copy()
        self.data.ctrl[self.aidx] = self.command(q)
        mujoco.mj_forward(self.model, self.data)

    def _step(self, hits: set[str]) -> None:
        """One physics step; contacts of the arm links (with anything) go into ``hits``."""
        m, d = self.model, self.data
        mujoco.mj_step(m, d)
        if d.ncon and self.arm_geom[d.contact.geom[: d.ncon]].any():
            hits.update(views.arm_collisions(m, d, self.links))

    def move(self, q) -> list[str]:
        """Drive along the straight joint-space line from the last target to ``q``, then settle;
        returns the contacts of the arm met at any physics step on the way."""
        m, d = self.model, self.data
        dt = m.opt.timestep
        q = np.asarray(q, dtype=float)
        q0 = d.qpos[self.qidx].copy() if self.target is None else self.target
        dq = q - q0
        steps = max(1, int(np.ceil(MIN_JERK_PEAK_SPEED * float(np.max(np.abs(dq)))
                                   / MOVE_SPEED / dt)))
        duration = steps * dt
        hits: set[str] = set()
        deviation = np.zeros(len(self.qidx))
        qpos, ctrl, iq, ia = self._qpos, self._ctrl, self._iq, self._ia
        # the reference of every step at once: per element the same products and sums as one
        # step at a time (q0 + s dq, ds / T dq, dds / T**2 dq)
        s, ds, dds = (np.array(c) for c in zip(*(min_jerk(i / steps)
                                                  for i in range(1, steps + 1)), strict=True))
        q_refs = q0 + s[:, None] * dq
        v_refs = (ds / duration)[:, None] * dq
        a_refs = (dds / duration ** 2)[:, None] * dq
        for q_ref, v_ref, a_ref in zip(q_refs, v_refs, a_refs, strict=True):
            ctrl[ia] = self.command(q_ref, v_ref, a_ref)
            self._step(hits)
            np.maximum(deviation, np.abs(qpos[iq] - q_ref), out=deviation)
        self.target = q.copy()
        ctrl[ia] = self.command(q)
        qvel, iv = self._qvel, self._iv
        for _ in range(int(SETTLE_MAX_TIME / dt)):
            self._step(hits)
            if np.max(np.abs(qvel[iv])) < SETTLE_SPEED:
                break
        mujoco.mj_forward(m, d)
        hits.update(views.arm_collisions(m, d, self.links))
        self.max_path_deviation = np.maximum(self.max_path_deviation, deviation)
        return sorted(hits)

    def measured_q(self) -> np.ndarray:
        return self.data.qpos[self.qidx].copy()


# ------------------------------------------------------------------------------------ view plan
#: File of a cached view plan (:func:`plan_views`), in its stage folder of the plan cache.
PLAN_FILE = "plan.json"


@functools.cache
def plan_sources() -> str:
    """Hash of the code a view plan runs (:mod:`sim.views` and what it imports of ``sim``,
    :mod:`artrecon.geometry` that the kinematics use), once per process: the code this
    process loaded (see :func:`sim.evaluate.stages.freeze_code_keys`)."""
    import artrecon.geometry
    from sim import cache

    return cache.hash_bytes(cache.closure_hash(views).encode(),
                            cache.closure_hash(artrecon.geometry, "artrecon").encode())


def plan_inputs(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
                K: np.ndarray, width: int, height: int, config: views.ViewPlanConfig) -> dict:
    """Everything :func:`sim.views.plan_capture` reads, as a dict for the plan cache's key.

    The compiled model itself (MuJoCo's binary model file, hashed: the scene file and every
    file it includes or references, the arm, the joint holds' targets), the state the plan
    starts from (joint positions, mocap poses), the arm's URDF when its kinematics come from
    one, the camera, the ring layout and seed, the planning code and the numerical packages.
    A scene file edited so that its compiled model changes gives another key; an edit that
    compiles to the same model (a comment) keeps the plan, which is the same plan.
    """
    import dataclasses

    import pinocchio

    from sim import cache

    buf = np.empty(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    state = cache.hash_bytes(*(np.ascontiguousarray(a, dtype=np.float64).tobytes()
                               for a in (data.qpos, data.mocap_pos, data.mocap_quat)))
    urdf = None
    if kin.spec.urdf is not None:
        urdf = cache.hash_files([robot.ROOT / kin.spec.urdf], root=robot.ROOT)
    return {"model": cache.hash_bytes(buf.tobytes()), "state": state, "arm": kin.spec.name,
            "urdf": urdf, "K": np.asarray(K, dtype=float).tolist(), "size": [width, height],
            "plan": dataclasses.asdict(config), "code": plan_sources(),
            "versions": {"numpy": np.__version__, "mujoco": mujoco.__version__,
                         "pinocchio": pinocchio.__version__}}


def plan_views(model: mujoco.MjModel, data: mujoco.MjData, kin: robot.ArmKinematics,
               K: np.ndarray, width: int, height: int, config: views.ViewPlanConfig, *,
               cache_dir=None, stage: str = "plan", progress=None) -> tuple[views.ViewPlan, bool]:
    """:func:`sim.views.plan_capture`, or the same plan read from ``cache_dir``.

    With ``cache_dir``, the plan is a stage of :func:`sim.cache.cached_stage` keyed by
    :func:`plan_inputs`: ``cache_dir/<stage>-<hash>/plan.json``, solved and stored when absent.
    The file holds every number of the plan exactly (:func:`sim.views.plan_to_json`), so a
    capture from a cached plan writes the same files as one that solved it. A large object's
    plan is most of its capture's CPU (drawer: 15 of 29 s), and it depends on none of what
    later code changes of the capture (rendering, the arm's motion, the files) touch.

    Returns
    -------
    plan : sim.views.ViewPlan
    cached : bool
        The plan came from the cache.
    """
    if cache_dir is None:
        return views.plan_capture(model, data, kin, K, width, height, config,
                                  progress=progress), False
    from sim import cache

    solved = []

    def build(folder: Path) -> dict:
        plan = views.plan_capture(model, data, kin, K, width, height, config, progress=progress)
        (folder / PLAN_FILE).write_text(json.dumps(views.plan_to_json(plan)) + "\n")
        solved.append(plan)
        return {"views": len(plan.views), "reachable": len(plan.reachable)}

    folder, _, hit = cache.cached_stage(cache_dir, stage,
                                        plan_inputs(model, data, kin, K, width, height, config),
                                        build)
    if not hit:
        return solved[0], False
    plan = views.plan_from_json(json.loads((folder / PLAN_FILE).read_text()))
    if progress is not None:
        progress.update(len(plan.views))
    return plan, True


# ------------------------------------------------------------------------------------ capture
def _scene_inputs(scene) -> list[Path]:
    """The scene file and every file it references (never to be written over), [] when the
    scene is not found (loading it says why)."""
    from sim.cache import scene_files
    from sim.scene import Scene, SceneError, scene_path

    try:
        path = scene.path if isinstance(scene, Scene) else scene_path(scene)
    except (SceneError, TypeError):
        return []
    return [path] + [f for f in scene_files(path) if f != path.resolve()]


def _check_out_dir(out_dir: Path, overwrite: bool, inputs=()) -> Path:
    out_dir = Path(out_dir).absolute()
    parent = out_dir.parent
    if not parent.is_dir():
        raise ValueError(f"cannot write the image set to {out_dir}: its parent folder {parent} "
                         "does not exist; create it or choose another --out")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise PermissionError(f"cannot write the image set to {out_dir}: folder {parent} is not "
                              "writable; choose another --out")
    # not on, around or inside the scene's files; a file is never replaced by the image set,
    # and --overwrite replaces only an image set (a folder holding cameras.json)
    check_output_path(out_dir, inputs, example=f"runs/{out_dir.name}")
    if out_dir.exists() and not overwrite:
        kind = "folder" if out_dir.is_dir() else "file"
        raise FileExistsError(f"{out_dir} already exists (a {kind}); remove it, choose another "
                              "--out, or pass --overwrite")
    return check_output_dir(out_dir, overwrite=overwrite, marker="cameras.json")


def capture(scene, config: str, out_dir, *, n_views: int = 36,
            elevations_deg: tuple[float, ...] = (20.0, 40.0, 60.0),
            top_elevations_deg: tuple[float, ...] = (70.0,), fill: float = 0.6,
            fill_range: tuple[float, float] = (0.45, 0.75),
            max_elevation_shift_deg: float = 10.0, seed: int = 0,
            free_camera_fallback: bool = False, overwrite: bool = False,
            progress: bool = True, plan_cache=None) -> CaptureResult:
    """Capture one image set of a scene in one configuration of its object.

    Parameters
    ----------
    scene : str, path or sim.scene.Scene
        A bundled scene's name (``"pliers"``), an MJCF path, or a loaded scene.
    config : {"a", "b"}
        Which configuration of the object to photograph.
    out_dir : path
        Folder to create (its parent must exist and be writable).
    n_views : int
        Views per full ring (36 keeps neighbours 10 degrees apart, as the method needs); rings near
        the top get proportionally fewer.
    elevations_deg, top_elevations_deg, fill, fill_range, max_elevation_shift_deg
        Ring layout, see :class:`sim.views.ViewPlanConfig`: desired elevations, the preferred
        share of the image the object fills and the band each ring's distance may take, and how
        far a ring's elevation may move when no distance in the band lets the arm reach all of it.
    seed : int
        Seeds each ring's first azimuth and the IK restarts. Same arguments, same files.
    free_camera_fallback : bool
        Photograph views the arm cannot reach with a free camera (pose unknown to the robot:
        ``T_world_camera`` is null in cameras.json). Off by default: those views are reported.
    overwrite : bool
        Replace an existing ``out_dir``.
    progress : bool
        Show a tqdm progress bar.
    plan_cache : path, optional
        Folder of cached view plans (:func:`plan_views`): the plan of these same inputs is read
        from there instead of solved, and a new one is stored there. The files written are the
        same either way.

    Returns
    -------
    CaptureResult
    """
    if config not in CONFIGS:
        raise ValueError(f"unknown configuration {config!r}; choose one of {CONFIGS}")
    plan_cfg = views.ViewPlanConfig(views_per_ring=n_views, elevations_deg=tuple(elevations_deg),
                                    top_elevations_deg=tuple(top_elevations_deg), fill=fill,
                                    fill_range=tuple(fill_range),
                                    max_elevation_shift_deg=max_elevation_shift_deg, seed=seed)
    out_dir = _check_out_dir(Path(out_dir), overwrite, _scene_inputs(scene))
    t_start = time.perf_counter()
    cpu_start, main_start = time.process_time(), time.thread_time()
    # the scene with its object joints held still while the arm works (sim.scene joint holds)
    sc = _load(scene).with_joint_holds()
    model = sc.model
    data = sc.make_data(config)  # arm at its home keyframe, object in the configuration
    sc.hold(data, config)

    kin = robot.load_arm_kinematics(model)
    cam_name = kin.spec.prefix + kin.spec.camera
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, cam_name)
    K, (width, height) = mujoco_camera_intrinsics(model, cam_name)
    joints_config = sc.configuration(config)

    expected = sum(n for _, n in views.ring_sizes(plan_cfg))
    bar = tqdm(total=2 * expected, desc=f"capture {sc.name}/{config}", unit="view",
               disable=not progress)
    plan, plan_cached = plan_views(model, data, kin, K, width, height, plan_cfg,
                                   cache_dir=plan_cache, stage=f"plan_{config}", progress=bar)
    centre, radius = plan.centre, plan.radius
    t_plan = time.perf_counter()
    plan_cpu = time.thread_time() - main_start
    log.info("%s config %s: %d views on %d rings around the object (radius %.3f m): %s", sc.name,
             config, len(plan.views), len(plan.rings), radius,
             ", ".join(f"{np.rad2deg(r.elevation):.1f} deg at {r.distance:.3f} m"
                       for r in plan.rings))
    reachable = plan.reachable
    to_take = [v for v in plan.views if v.reachable or free_camera_fallback]
    bar.total = len(plan.views) + len(to_take)
    bar.n = len(plan.views)
    bar.refresh()
    if len(to_take) < MIN_CAPTURED_VIEWS:
        bar.close()
        raise CaptureError(
            f"only {len(reachable)} of {len(plan.views)} planned views of {sc.name!r} are "
            f"reachable (need {MIN_CAPTURED_VIEWS}); use more views per ring (--views), other "
            f"elevations, or --free-camera-fallback. First reasons: "
            + "; ".join(f"view {v.index}: {v.reason}" for v in plan.unreachable[:3]))

    arm_root = int(model.jnt_bodyid[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT,
                                                      kin.joint_names[0])])
    link_names = [li.name for li in sc.links]
    renderer = render.MjRenderer(model, geom_labels=_geom_labels(model, sc, arm_root))
    arm = _Arm(model, data, kin)
    if reachable:
        arm.place(reachable[0].q)

    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=out_dir.parent))
    # PNGs are compressed and written in a background thread (zlib releases the GIL) while the
    # arm moves to the next view
    writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="capture-png")
    writes = []
    try:
        for sub in ("images", "ground_truth/depth", "ground_truth/labels"):
            (tmp / sub).mkdir(parents=True)
        cam_images, gt_images, free = [], [], []
        t_move = t_render = move_cpu = png_cpu = 0.0
        max_dp = max_dr = 0.0
        for i, view in enumerate(to_take):
            name = f"{i:03d}.png"
            t0, c0 = time.perf_counter(), time.thread_time()
            path_hits: list[str] = []
            if view.reachable:
                path_hits = arm.move(view.q)
                if path_hits:
                    raise CaptureError(
                        f"the arm touched {', '.join(path_hits)} on its way to view {i} of "
                        f"{sc.name!r} (ring {view.ring}, azimuth "
                        f"{np.rad2deg(view.azimuth):.0f} deg): the planned views are "
                        "collision-free but the straight joint-space move between them is not; "
                        "try other elevations or --views")
            joints_now = _joint_values(sc, data)
            drift = max((abs(joints_now[k] - joints_config[k]) for k in joints_now), default=0.0)
            if drift > OBJECT_DRIFT_TOL:
                raise CaptureError(
                    f"the arm moved the object of {sc.name!r} by {drift:.2e} (rad or m) while "
                    f"reaching view {i} (contacts: {', '.join(path_hits) or 'none seen'}); the "
                    "scene or the view plan lets the arm hit the object")
            T_true = convert_camera_pose(np.r_[np.c_[data.cam_xmat[cam_id].reshape(3, 3),
                                                     data.cam_xpos[cam_id]], [[0, 0, 0, 1]]])
            if view.reachable:
                q = arm.measured_q()
                T_fk = kin.camera_pose(q)
                dp = float(np.linalg.norm(T_fk[:3, 3] - T_true[:3, 3]))
                dr = rotation_angle(T_fk[:3, :3].T @ T_true[:3, :3])
                max_dp, max_dr = max(max_dp, dp), max(max_dr, dr)
                T_render = T_true
            else:
                q, T_fk, dp, dr = None, None, None, None
                T_render = view.T_world_camera
                free.append(i)
            t1 = time.perf_counter()
            move_cpu += time.thread_time() - c0
            out = renderer.render(data, K, T_render, width, height, depth=True, labels=True)
            t2 = time.perf_counter()
            t_move += t1 - t0
            t_render += t2 - t1
            writes.append(writer.submit(_write_pngs, (
                (out.color, tmp / "images" / name, "colour"),
                (_depth_png(out.depth), tmp / "ground_truth" / "depth" / name, "depth"),
                (_labels_png(out.labels), tmp / "ground_truth" / "labels" / name, "labels"))))
            cam_images.append({
                "file": name,
                "pose_source": "arm_fk" if view.reachable else "free_camera",
                "q": None if q is None else [float(x) for x in q],
                "T_world_camera": None if T_fk is None else _as_list(T_fk),
                "T_world_flange": None if q is None else _as_list(kin.frame_pose(q, "flange")),
            })
            gt_images.append({
                "file": name,
                "view": {"ring": view.ring, "azimuth_deg": float(np.rad2deg(view.azimuth)),
                         "elevation_deg": float(np.rad2deg(view.elevation)),
                         "distance_m": view.distance, "roll_deg": view.roll_deg},
                "T_world_camera": _as_list(T_render),
                "fk_position_error_m": dp,
                "fk_rotation_error_rad": dr,
                "object_joints": joints_now,
                "link_poses": {li.name: _as_list(np.r_[np.c_[
                    data.xmat[li.body_id].reshape(3, 3), data.xpos[li.body_id]], [[0, 0, 0, 1]]])
                    for li in sc.links},
            })
            bar.update(1)
        bar.close()
        unreachable = [{"ring": v.ring, "azimuth_deg": float(np.rad2deg(v.azimuth)),
                        "elevation_deg": float(np.rad2deg(v.elevation)), "reason": v.reason}
                       for v in plan.unreachable]
        cameras = {
            "format": "artrecon-capture/1",
            "scene": sc.name,
            "config": config,
            "convention": "OpenCV camera (x right, y down, z forward); T_world_camera maps camera "
                          "coordinates to world coordinates; metres, radians",
            "width": width, "height": height, "K": _as_list(K),
            "joint_names": list(kin.joint_names),
            "images": cam_images,
        }
        report = {
            "scene": sc.name, "config": config, "seed": seed, "views_per_ring": n_views,
            "elevations_deg": list(elevations_deg), "top_elevations_deg": list(top_elevations_deg),
            "fill": fill, "fill_range": list(fill_range),
            "max_elevation_shift_deg": max_elevation_shift_deg,
            "rings": [{"ring": r.index, "n_views": r.n_views,
                       "desired_elevation_deg": float(np.rad2deg(r.desired_elevation)),
                       "elevation_deg": float(np.rad2deg(r.elevation)),
                       "distance_m": r.distance, "fill": r.fill,
                       "candidates_tried": r.candidates_tried} for r in plan.rings],
            "planned": len(plan.views), "captured": len(to_take),
            "free_camera_images": free, "unreachable": unreachable,
            "max_path_deviation": dict(zip(kin.joint_names,
                                           arm.max_path_deviation.tolist(), strict=True)),
        }
        truth = {
            "scene": sc.name, "config": config,
            "object_joints": joints_config,
            "object_links": link_names,
            "object_bounding_sphere": {"centre": [float(x) for x in centre], "radius": radius},
            "label_legend": {**{str(i): n for i, n in enumerate(link_names)},
                             str(LABEL_PNG_ARM): "arm", str(LABEL_PNG_STAGE): "stage",
                             str(LABEL_PNG_BACKGROUND): "background"},
            "depth_png_scale_m": DEPTH_PNG_SCALE,
            "images": gt_images,
        }
        for w in writes:
            png_cpu += w.result()  # raises the first failed write
        for path, obj in ((tmp / "cameras.json", cameras), (tmp / "capture.json", report),
                          (tmp / "ground_truth" / "poses.json", truth)):
            path.write_text(json.dumps(obj, indent=2) + "\n")
        os.chmod(tmp, 0o755)
        if out_dir.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".old",
                                        dir=out_dir.parent))
            os.replace(out_dir, old / "set")
            os.replace(tmp, out_dir)
            shutil.rmtree(old)
        else:
            os.replace(tmp, out_dir)
    except BaseException:
        bar.close()
        writer.shutdown(wait=True, cancel_futures=True)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        writer.shutdown(wait=True)
    t_end = time.perf_counter()
    cpu = time.process_time() - cpu_start
    n = max(1, len(to_take))
    result = CaptureResult(
        out_dir=out_dir, n_planned=len(plan.views), n_captured=len(to_take),
        unreachable=unreachable, free_camera=free, max_fk_position_error=max_dp,
        max_fk_rotation_error=max_dr, plan_cached=plan_cached,
        timings={"plan_s": t_plan - t_start, "move_s": t_move, "render_s": t_render,
                 "total_s": t_end - t_start,
                 "render_ms_per_image": 1e3 * t_render / n,
                 # CPU seconds (all threads: main, llvmpipe's rasteriser, the PNG writer);
                 # render_cpu_s is the rest: rendering, ground-truth conversion, bookkeeping
                 "cpu_s": cpu, "plan_cpu_s": plan_cpu, "move_cpu_s": move_cpu,
                 "png_cpu_s": png_cpu, "render_cpu_s": cpu - plan_cpu - move_cpu - png_cpu})
    log.info("%s config %s: %d/%d views captured into %s (%.1f s)", sc.name, config,
             result.n_captured, result.n_planned, out_dir, result.timings["total_s"])
    return result


#: The fresh view (:func:`capture_fresh_view`) lies between the first two capture rings (20 and
#: 40 degrees by default), so no image of a set was taken from there ...
FRESH_ELEVATION_DEG = 30.0
#: ... and half a capture step (10 degrees at 36 views per ring) off the arm's current azimuth;
#: further offsets are tried when that one is out of reach.
FRESH_AZIMUTH_OFFSETS_DEG = (5.0, 15.0, -5.0, -15.0, 25.0, -25.0, 35.0, -35.0)


@dataclass
class FreshView:
    """What :func:`capture_fresh_view` wrote."""

    image: Path
    """the image file"""
    pose_file: Path
    """``{"q", "T_world_flange", "T_world_camera"}``: what the robot knows (FK of its joints)"""
    q: np.ndarray
    """the arm's joint angles at the view (rail first)"""
    T_world_flange: np.ndarray
    """flange pose from FK (m)"""
    T_world_camera_true: np.ndarray
    """the camera's true pose (scoring only; ``ground_truth.json`` beside the image)"""


def capture_fresh_view(scene, config: str, q_start, out_dir, *, fill: float = 0.6,
                       seed: int = 0) -> FreshView:
    """One more image after the capture, from an arm pose that neither image set holds.

    The arm starts at ``q_start`` (where the capture left it), plans a view at
    :data:`FRESH_ELEVATION_DEG` half a capture step off its current azimuth (other offsets when
    that one is out of reach), moves there in physics along a checked line and photographs the
    object. Writes ``out_dir/fresh.png``, ``out_dir/pose.json`` (joint angles, flange and camera
    pose from forward kinematics: what the robot knows) and ``out_dir/ground_truth.json`` (the
    true camera pose, scoring only), whole or not at all.

    Raises
    ------
    CaptureError
        No offset gives a reachable, collision-free view with a clear path.
    """
    out_dir = _check_out_dir(Path(out_dir), overwrite=False)
    sc = _load(scene).with_joint_holds()
    model = sc.model
    data = sc.make_data(config)
    sc.hold(data, config)
    kin = robot.load_arm_kinematics(model)
    cam_name = kin.spec.prefix + kin.spec.camera
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, cam_name)
    K, (width, height) = mujoco_camera_intrinsics(model, cam_name)
    q_start = np.asarray(q_start, dtype=float)
    data.qpos[robot.qpos_indices(model, kin)] = q_start
    mujoco.mj_forward(model, data)
    centre, radius = views.object_bounding_sphere(model, data)
    distance = views.ring_distance(radius, K, width, height, fill)
    eye = kin.camera_pose(q_start)[:3, 3] - centre
    az0 = float(np.arctan2(eye[1], eye[0]))
    el = np.deg2rad(FRESH_ELEVATION_DEG)
    reasons = []
    chosen = None
    for k, off in enumerate(FRESH_AZIMUTH_OFFSETS_DEG):
        az = az0 + np.deg2rad(off)
        pos = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                            np.sin(el)])
        view = views.View(k, 0, az, el, distance, robot.look_at_pose(pos, centre))
        views.solve_views(model, data, kin, [view], seed=seed, q_start=q_start)
        if view.reachable:
            views.check_paths(model, data, kin, [view], q_start=q_start)
        if view.reachable:
            chosen = view
            break
        reasons.append(f"{off:+.0f} deg: {view.reason}")
    if chosen is None:
        raise CaptureError(f"no fresh view of {sc.name!r} is reachable near the arm's pose: "
                           + "; ".join(reasons[:3]))
    arm = _Arm(model, data, kin)
    arm.place(q_start)
    hits = arm.move(chosen.q)
    if hits:
        raise CaptureError(f"the arm touched {', '.join(hits)} on its way to the fresh view of "
                           f"{sc.name!r}")
    q = arm.measured_q()
    T_true = convert_camera_pose(np.r_[np.c_[data.cam_xmat[cam_id].reshape(3, 3),
                                             data.cam_xpos[cam_id]], [[0, 0, 0, 1]]])
    renderer = render.MjRenderer(model)
    color = renderer.render(data, K, T_true, width, height).color
    T_flange = kin.frame_pose(q, "flange")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=out_dir.parent))
    try:
        (tmp / "fresh.png").write_bytes(_png_bytes(color, "colour"))
        pose = {"scene": sc.name, "config": config, "q": [float(x) for x in q],
                "joint_names": list(kin.joint_names), "K": _as_list(K),
                "T_world_flange": _as_list(T_flange),
                "T_world_camera": _as_list(kin.camera_pose(q)),
                "view": {"azimuth_deg": float(np.rad2deg(chosen.azimuth)),
                         "elevation_deg": FRESH_ELEVATION_DEG, "distance_m": distance,
                         "roll_deg": chosen.roll_deg}}
        (tmp / "pose.json").write_text(json.dumps(pose, indent=2) + "\n")
        (tmp / "ground_truth.json").write_text(json.dumps(
            {"T_world_camera": _as_list(T_true)}, indent=2) + "\n")
        os.chmod(tmp, 0o755)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return FreshView(out_dir / "fresh.png", out_dir / "pose.json", q, T_flange, T_true)


def main(argv=None) -> int:
    """Command line: ``python -m sim.capture SCENE --config a|b --out DIR``."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m sim.capture", description=__doc__.split("\n")[0])
    p.add_argument("scene", help="a bundled scene's name (pliers, truck, drawer) or an MJCF path")
    p.add_argument("--config", required=True, help="object configuration: a or b")
    p.add_argument("--out", required=True, type=Path, help="image set folder to create")
    p.add_argument("--views", type=int, default=36,
                   help="views per full ring (default 36: neighbours 10 degrees apart)")
    p.add_argument("--seed", type=int, default=0, help="seed of ring phases and IK restarts")
    p.add_argument("--fill", type=float, default=0.6,
                   help="preferred share of the shorter image side the object's bounding sphere "
                        "fills (each ring may take 0.45-0.75 so that the arm reaches it)")
    p.add_argument("--free-camera-fallback", action="store_true",
                   help="photograph views the arm cannot reach with a free camera")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    p.add_argument("--plan-cache", type=Path, metavar="DIR",
                   help="reuse the view plan (rings and IK) of the same scene, configuration, "
                        "views and seed stored in DIR, and store new plans there")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    problem = views.views_problem(args.views)
    if problem:
        p.error(problem)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        res = capture(args.scene, args.config, args.out, n_views=args.views, seed=args.seed,
                      fill=args.fill, free_camera_fallback=args.free_camera_fallback,
                      overwrite=args.overwrite, progress=not args.quiet,
                      plan_cache=args.plan_cache)
    except (ValueError, FileNotFoundError, FileExistsError, PermissionError,
            CaptureError) as e:
        p.exit(2, f"error: {e}\n")
    except KeyboardInterrupt:
        p.exit(130, f"interrupted; {args.out} is as it was (run again to capture)\n")
    out = sys.stdout
    out.write(f"{res.n_captured}/{res.n_planned} views captured into {res.out_dir}\n")
    for u in res.unreachable:
        out.write(f"  unreachable: ring {u['ring']} azimuth {u['azimuth_deg']:.0f} deg: "
                  f"{u['reason']}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
