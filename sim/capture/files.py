"""The files of an image set: the colour, depth and label PNGs (encoded, written and read back),
the label codes, and the output folder (checked before any work; built in
:func:`artrecon.files.make_work_dir` and published whole by :func:`artrecon.files.publish_dir`)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import mujoco
import numpy as np
from PIL import Image

from artrecon.files import check_output_dir, check_output_path
from sim.cache import scene_files
from sim.capture.rig import CaptureError
from sim.render import LABEL_BACKGROUND
from sim.scene import Scene, SceneError, scene_path

#: Label codes in ground_truth/labels/*.png.
LABEL_PNG_ARM = 253
LABEL_PNG_STAGE = 254
LABEL_PNG_BACKGROUND = 255
#: Renderer labels of the arm (rail carriage and everything on it) and of the rest of the stage.
LABEL_ARM = -2
LABEL_STAGE = -3
#: Depth PNG unit (m): 0.1 mm, far below the 1 mm scoring tolerance; range up to 6.55 m.
DEPTH_PNG_SCALE = 1e-4


# ------------------------------------------------------------------------------------ labels, depth
def geom_labels(model: mujoco.MjModel, sc: Scene, arm_root: int) -> np.ndarray:
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


def labels_png(labels: np.ndarray) -> np.ndarray:
    """The uint8 label image of a renderer label image (:data:`LABEL_PNG_ARM` ...)."""
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
    out[png == LABEL_PNG_BACKGROUND] = LABEL_BACKGROUND
    return out


def depth_png(depth: np.ndarray) -> np.ndarray:
    """The uint16 depth image (units of :data:`DEPTH_PNG_SCALE`, 0 = none) of a depth in m."""
    units = np.round(np.asarray(depth, dtype=np.float64) / DEPTH_PNG_SCALE)
    units[(units <= 0) | (units > 65535)] = 0
    return units.astype(np.uint16)


def read_depth_png(path) -> np.ndarray:
    """Depth (m) : (h, w) float from a ground-truth depth PNG (0 where no surface)."""
    return np.asarray(Image.open(path), dtype=np.float64) * DEPTH_PNG_SCALE


# ------------------------------------------------------------------------------------ PNG files
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


def png_bytes(array: np.ndarray, kind: str) -> bytes:
    """A PNG file's bytes of an (h, w, 3) uint8 RGB image (``kind`` "colour") or an (h, w)
    uint16 / uint8 image ("depth", "labels")."""
    if array.ndim == 3:
        array = np.ascontiguousarray(array[:, :, ::-1])  # OpenCV takes BGR
    ok, buf = cv2.imencode(".png", array, list(PNG_PARAMS[kind]))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {kind} PNG of shape {array.shape}")
    return buf.tobytes()


def write_pngs(items) -> float:
    """Write ``(array, path, kind)`` triples as PNG files (kind: a key of :data:`PNG_PARAMS`);
    returns the CPU seconds this thread spent on it."""
    t0 = time.thread_time()
    for array, path, kind in items:
        Path(path).write_bytes(png_bytes(array, kind))
    return time.thread_time() - t0


def as_list(T) -> list:
    """A matrix as nested lists of Python floats (for JSON)."""
    return [[float(x) for x in row] for row in np.asarray(T)]


# ------------------------------------------------------------------------------------ the folder
def scene_inputs(scene) -> list[Path]:
    """The scene file and every file it references (never to be written over), [] when the
    scene is not found (loading it says why)."""
    try:
        path = scene.path if isinstance(scene, Scene) else scene_path(scene)
    except (SceneError, TypeError):
        return []
    return [path] + [f for f in scene_files(path) if f != path.resolve()]


def check_out_dir(out_dir: Path, overwrite: bool, inputs=()) -> Path:
    """``out_dir``, absolute, once it may be written: its parent exists and is writable, it is
    none of ``inputs`` nor around or inside them, and it is absent (or, with ``overwrite``, an
    image set)."""
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
