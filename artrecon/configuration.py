"""The per-configuration stage: one image set in, its cameras and dense object points out.

Everything the reconstruction does with one configuration alone (SfM, dense points, the object
told from the background) is this stage, so the two configurations can run side by side (two
processes, or the two capture processes of the harness) and a later run can start from their
folders. Its folder (``OUT/a`` or ``OUT/b``) is a contract::

    database.db, pairs.txt, colmap.log   SIFT features and verified matches (COLMAP)
    sparse/0/                             the SfM model (COLMAP's layout)
    dense.ply                             the object's dense oriented points (SfM frame)
    dense_views.npz                       which images see each dense point; the dense points
                                          near the object, background included (occluders)
    region.npz                            SfM point ids on the object and a background sample
    configuration.json                    the record: inputs, settings, figures, timings

:func:`reconstruct_configuration` writes it (whole or not at all), :func:`load_configuration`
reads it back; a folder whose record names the same inputs and settings is reused.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pycolmap
from threadpoolctl import threadpool_limits

from artrecon._version import __version__
from artrecon.dense import DenseConfig, DensePoints, RegionConfig, fused_points, object_region
from artrecon.errors import InputError, ReconstructionError
from artrecon.files import read_json, read_ply, write_json_atomic, write_ply
from artrecon.io import ImageSet, Intrinsics, load_cameras_json
from artrecon.sfm import SfMConfig, SfMResult, layout_error, run_sfm

log = logging.getLogger(__name__)

#: Version of the folder contract (``configuration.json`` ``format``).
FORMAT = "artrecon-configuration/1"
#: Background SfM points (per configuration) that take part in the cross-configuration matching,
#: only to tell which link stays put with the room (the root). A sample keeps the matching cost
#: down.
BACKGROUND_SAMPLE = 3000


@dataclass
class Configuration:
    """What the per-configuration stage found for one image set.

    Attributes
    ----------
    sfm : SfMResult
        Cameras and sparse points.
    dense : DensePoints
        The object's dense oriented points.
    occluders : (m, 3) float
        Dense points near the object, background included (the table hides things too).
    object_ids, background_ids : set of int
        SfM point ids on the object, and a sample of those on the background.
    record : dict
        ``configuration.json``.
    """

    sfm: SfMResult
    dense: DensePoints
    occluders: np.ndarray
    object_ids: set = field(default_factory=set)
    background_ids: set = field(default_factory=set)
    record: dict = field(default_factory=dict)


def _cameras(sfm: SfMResult) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres (m, 3) and viewing directions (m, 3) of the registered images."""
    T = sfm.T_world_camera()
    names = sorted(T)
    return np.array([T[n][:3, 3] for n in names]), np.array([T[n][:3, 2] for n in names])


def inputs_digest(image_set: ImageSet, intrinsics: Intrinsics | None, poses, settings: dict,
                  seed: int) -> str:
    """SHA-256 of everything the stage's result depends on: the images' bytes, the intrinsics,
    the camera poses, the object's region (with the poses), the settings, the seed and
    artrecon's version."""
    h = hashlib.sha256()
    region = image_set.region if poses is not None else None
    h.update(json.dumps({"names": image_set.names, "digests": list(image_set.digests),
                         "region": None if region is None else
                         np.asarray(region).round(12).tolist(),
                         "K": None if intrinsics is None else intrinsics.K.tolist(),
                         "poses": None if poses is None else
                         {k: np.asarray(v).round(12).tolist() for k, v in sorted(poses.items())},
                         "settings": settings, "seed": seed, "version": __version__},
                        sort_keys=True, default=str).encode())
    return h.hexdigest()


def stage_settings(sfm_config: SfMConfig | None = None, dense_config: DenseConfig | None = None,
                   region_config: RegionConfig | None = None) -> dict:
    """The settings the stage depends on, as its record holds them (``settings``) and
    :func:`inputs_digest` hashes them (default: each stage's defaults)."""
    return {"sfm": asdict(sfm_config or SfMConfig()),
            "dense": asdict(dense_config or DenseConfig()),
            "region": asdict(region_config or RegionConfig())}


def check_reusable(folder: str | Path, image_set: ImageSet, intrinsics: Intrinsics | None,
                   poses, settings: dict, seed: int, *, which: str = "",
                   restart: str = "run from the start") -> dict:
    """Refuse a folder that is not a finished stage of exactly these inputs and settings.

    :func:`reconstruct_configuration` quietly recomputes such a folder; a run told to start
    after this stage (``artrecon reconstruct --from matches`` or any later stage) must not, so
    it asks here first.

    Parameters
    ----------
    folder : str or Path
    image_set, intrinsics, poses, settings, seed
        What this run would compute the stage from (``settings`` as :func:`stage_settings`).
    which : str
        ``"A"`` or ``"B"``, for messages.
    restart : str
        What the user should do instead, for messages.

    Returns
    -------
    dict
        The folder's record.

    Raises
    ------
    InputError
        The folder holds no finished stage (no record), a record of another format, one made
        from other inputs or settings (the message names what differs), or one whose images
        are no longer where the record says.
    """
    folder = Path(folder)
    record_path = folder / "configuration.json"
    if not record_path.is_file():
        raise InputError(f"configuration {which}: {folder} holds no finished configuration stage "
                         f"(no configuration.json); {restart}")
    record = read_json(record_path)
    if record.get("format") != FORMAT:
        raise InputError(f"{record_path}: format {record.get('format')!r}, this artrecon reads "
                         f"{FORMAT!r}; {restart}")
    if record.get("inputs_digest") != inputs_digest(image_set, intrinsics, poses, settings,
                                                    seed):
        differs = "; ".join(_differences(record, image_set, poses, settings, seed))
        raise InputError(f"configuration {which}: {folder} was made from other inputs or "
                         f"settings than this run's ({differs}), so it is not reused; "
                         f"{restart}, or give the inputs and settings it was made with")
    image_dir = Path(record["image_dir"])
    if not image_dir.is_dir():
        raise InputError(f"{record_path}: its images were in {image_dir}, which is not a folder "
                         f"now (moved or deleted?); the later stages read them again: put them "
                         f"back, or {restart}")
    return record


def _differences(record: dict, image_set: ImageSet, poses, settings: dict, seed: int
                 ) -> list[str]:
    """What a record names otherwise than this run (for :func:`check_reusable`'s message)."""
    out = []
    if record.get("artrecon_version") != __version__:
        out.append(f"artrecon {record.get('artrecon_version')} made it, this is {__version__}")
    if record.get("seed") != seed:
        out.append(f"seed {record.get('seed')} there, {seed} now")
    cameras = "given poses (held fixed)" if poses is not None else "SfM from the images"
    if record.get("cameras") != cameras:
        out.append(f"cameras: {record.get('cameras')} there, {cameras} now")
    # the settings as the record holds them (JSON: tuples are lists)
    now = json.loads(json.dumps(settings, default=str))
    there = record.get("settings") or {}
    for stage in sorted(set(now) | set(there)):
        a, b = there.get(stage) or {}, now.get(stage) or {}
        out += [f"{stage}.{k}: {a.get(k)!r} there, {b.get(k)!r} now"
                for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    if record.get("num_images") != len(image_set.names):
        out.append(f"{record.get('num_images')} images there, {len(image_set.names)} now")
    elif record.get("image_dir") != os.path.abspath(image_set.image_dir):
        out.append(f"images from {record.get('image_dir')} there, "
                   f"{os.path.abspath(image_set.image_dir)} now")
    return out or ["the images' contents, the intrinsics or the camera poses"]


#: Given intrinsics whose focal lengths differ from a capture's cameras.json by more than this
#: fraction are named as the cause when the SfM cameras disagree with the capture's poses.
INTRINSICS_MISMATCH = 0.02


def _layout_cause(intrinsics: Intrinsics | None, reference: Intrinsics) -> str:
    """The likely cause of SfM cameras that disagree with a capture's poses, for the message:
    intrinsics (held fixed in SfM) other than the capture's own, else a folded camera ring."""
    if intrinsics is not None:
        f_given = np.array([intrinsics.K[0, 0], intrinsics.K[1, 1]])
        f_ref = np.array([reference.K[0, 0], reference.K[1, 1]])
        ratio = f_given / f_ref
        if np.max(np.abs(ratio - 1.0)) > INTRINSICS_MISMATCH:
            return (f". Likely cause: the intrinsics. The given focal lengths (fx, fy = "
                    f"{f_given[0]:.1f}, {f_given[1]:.1f} px) are {ratio.mean():.2f} x those of "
                    f"the camera file ({f_ref[0]:.1f}, {f_ref[1]:.1f} px); SfM holds given "
                    "intrinsics fixed, so wrong ones bend the cameras' layout. Pass the right "
                    "intrinsics (--intrinsics fx,fy,cx,cy in pixels of these images), or leave "
                    "--intrinsics out: the capture's cameras.json then supplies them")
    return ("; a folded or broken camera ring: use the poses (--use-poses) or more overlapping "
            "views")


def reconstruct_configuration(image_set: ImageSet, out_dir: str | Path,
                              intrinsics: Intrinsics | None = None, poses=None, *,
                              sfm_config: SfMConfig | None = None,
                              dense_config: DenseConfig | None = None,
                              region_config: RegionConfig | None = None, seed: int = 0,
                              which: str = "", progress: bool = False) -> Configuration:
    """Cameras, dense object points and the object region of one image set, into ``out_dir``.

    Parameters
    ----------
    image_set : ImageSet
    out_dir : str or Path
        The stage's folder (see the module docstring). Its contents are replaced unless its
        record names the same inputs, in which case it is read back and nothing is computed.
    intrinsics : Intrinsics, optional
    poses : dict of str to (4, 4) float, optional
        Known ``T_world_camera`` per image (the arm's forward kinematics), held fixed.
    sfm_config, dense_config, region_config : optional
        The stages' settings (default: their defaults).
    seed : int
    which : str
        ``"A"`` or ``"B"``, for messages.
    progress : bool

    Returns
    -------
    Configuration

    Raises
    ------
    ReconstructionError
        SfM failed, the SfM cameras disagree with a capture's reference poses, or nothing of
        the object is left after removing the background.
    """
    # A and B run side by side (two processes): one core each, for BLAS and OpenCV alike
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            return _reconstruct_configuration(image_set, Path(out_dir), intrinsics, poses,
                                              sfm_config, dense_config, region_config, seed,
                                              which, progress)
    finally:
        cv2.setNumThreads(threads)


def _reconstruct_configuration(image_set, out_dir: Path, intrinsics, poses, sfm_config,
                               dense_config, region_config, seed: int, which: str,
                               progress: bool) -> Configuration:
    sfm_config = sfm_config or SfMConfig()
    dense_config = dense_config or DenseConfig()
    region_config = region_config or RegionConfig()
    settings = stage_settings(sfm_config, dense_config, region_config)
    digest = inputs_digest(image_set, intrinsics, poses, settings, seed)
    record_path = out_dir / "configuration.json"
    if record_path.is_file():
        try:
            if read_json(record_path).get("inputs_digest") == digest:
                log.info("configuration %s: reusing %s (same images and settings)", which, out_dir)
                return load_configuration(out_dir)
        except (InputError, ReconstructionError) as exc:
            log.warning("configuration %s: %s cannot be reused (%s); recomputing", which,
                        out_dir, exc)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    reference_intrinsics, reference = None, {}
    if poses is None and image_set.cameras_file is not None:
        reference_intrinsics, reference = load_cameras_json(image_set.cameras_file)
    # without reference poses to check the cameras' layout against, the images check the given
    # focal length (held fixed in SfM) themselves
    sfm = run_sfm(image_set, out_dir, intrinsics, poses, sfm_config, seed, progress,
                  check_focal=len(reference) < 3)
    layout = None
    if len(reference) >= 3:
        layout = layout_error(sfm, reference)
        log.info("configuration %s: SfM cameras vs cameras.json poses: %.2f%% of their spread",
                 which, 100 * layout)
        if layout > sfm_config.max_layout_error:
            raise ReconstructionError(
                f"configuration {which}: the SfM cameras disagree with the poses in "
                f"{image_set.cameras_file} by {100 * layout:.1f}% of their spread"
                + _layout_cause(intrinsics, reference_intrinsics))
    timings["sfm"] = time.perf_counter() - t
    t, cpu = time.perf_counter(), time.process_time()
    cloud = fused_points(sfm, dense_config)
    centres, axes = _cameras(sfm)
    occluders = cloud.points  # background too: the table and walls hide things
    # normals for the object's points only (a few percent of a full-resolution cloud; the
    # occluders need none), each from its neighbours in the whole cloud as before
    dense = cloud.oriented(object_region(cloud.points, centres, axes, region_config, seed))
    # what the folder holds (float32 in PLY): a run that reads the folder back finds the same
    occluders = occluders.astype(np.float32).astype(float)
    dense = DensePoints(dense.points.astype(np.float32).astype(float),
                        dense.normals.astype(np.float32).astype(float), dense.colors,
                        dense.visibility, dense.image_names)
    if len(dense) < 10:
        raise ReconstructionError(f"configuration {which}: no dense points left on the object "
                                  "after removing the background; the cameras should circle the "
                                  "object and look at it")
    rec = sfm.reconstruction
    ids = np.array(list(rec.point3D_ids()), dtype=np.int64)
    xyz = np.array([rec.points3D[int(i)].xyz for i in ids]) if len(ids) else np.zeros((0, 3))
    on_object = object_region(xyz, centres, axes, region_config, seed)
    bg = ids[~on_object]
    if len(bg) > BACKGROUND_SAMPLE:
        bg = np.random.default_rng(seed).choice(bg, BACKGROUND_SAMPLE, replace=False)
    timings["dense"] = time.perf_counter() - t
    timings["dense_cpu"] = time.process_time() - cpu  # this process: one stage at a time
    write_ply(out_dir / "dense.ply", dense.points, dense.normals, dense.colors)
    np.savez(out_dir / "dense_views.npz", visibility=np.packbits(dense.visibility, axis=1),
             n_images=len(dense.image_names), image_names=np.array(dense.image_names),
             occluders=occluders.astype(np.float32))
    np.savez(out_dir / "region.npz", object_ids=ids[on_object], background_ids=bg)
    record = {
        "format": FORMAT, "configuration": which, "inputs_digest": digest,
        "artrecon_version": __version__, "seed": seed,
        # absolute: the later stages read the images again (dense labels, free space), and a
        # path relative to the working directory of the run that wrote it pointed elsewhere,
        # or nowhere, from another one
        "images": os.path.abspath(image_set.root),
        "image_dir": os.path.abspath(image_set.image_dir), "num_images": len(image_set.names),
        "cameras": "given poses (held fixed)" if poses is not None else "SfM from the images",
        "registered_images": rec.num_reg_images(), "sparse_points": rec.num_points3D(),
        "dense_points": len(dense), "pose_agreement": sfm.pose_agreement,
        "layout_error": layout, "focal_check": sfm.focal_check,
        "timings": {**timings, **{f"sfm_{k}": v for k, v in sfm.timings.items()}},
        "settings": settings,
    }
    write_json_atomic(record_path, record)  # last: a folder without it is incomplete
    return Configuration(sfm, dense, occluders, set(ids[on_object].tolist()),
                         set(bg.tolist()), record)


def load_configuration(folder: str | Path) -> Configuration:
    """Read a folder written by :func:`reconstruct_configuration`.

    Raises
    ------
    ReconstructionError
        The folder is incomplete (no record: an interrupted run) or of another format.
    """
    folder = Path(folder)
    record_path = folder / "configuration.json"
    if not record_path.is_file():
        raise ReconstructionError(f"{folder} holds no finished configuration stage (no "
                                  "configuration.json); run the reconstruction again")
    record = read_json(record_path)
    if record.get("format") != FORMAT:
        raise ReconstructionError(f"{record_path}: format {record.get('format')!r}, this "
                                  f"artrecon reads {FORMAT!r}; reconstruct again")
    image_dir = Path(record["image_dir"])
    if not image_dir.is_dir():
        raise ReconstructionError(f"{record_path}: its images were in {image_dir}, which is not a "
                                  "folder now (moved or deleted?); the later stages read them "
                                  "again: put them back or reconstruct again")
    rec = pycolmap.Reconstruction(str(folder / "sparse" / "0"))
    sfm = SfMResult(rec, folder / "database.db", image_dir,
                    folder / "sparse" / "0", int(record["num_images"]),
                    record.get("timings", {}), record.get("pose_agreement"),
                    record.get("focal_check"))
    points, normals, colours = read_ply(folder / "dense.ply")
    views = np.load(folder / "dense_views.npz")
    n_images = int(views["n_images"])
    visibility = np.unpackbits(views["visibility"], axis=1, count=n_images).astype(bool)
    dense = DensePoints(points, normals, colours, visibility,
                        [str(x) for x in views["image_names"]])
    region = np.load(folder / "region.npz")
    return Configuration(sfm, dense, np.asarray(views["occluders"], float),
                         set(region["object_ids"].tolist()),
                         set(region["background_ids"].tolist()), record)
