"""Input of the reconstruction: image folders, camera intrinsics and optional camera poses.

An image set is a folder of photos of one configuration of the object. Either the folder holds
the images itself, or it is a capture folder with ``images/`` inside and, optionally, a
``cameras.json`` beside it (intrinsics ``K`` and per-image ``T_world_camera``, OpenCV convention,
as written by ``sim.capture`` from the arm's forward kinematics). Nothing else in a capture folder
is opened here (in particular never ``ground_truth/``).

``cameras.json`` layout::

    {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": W, "height": H,
     "images": [{"name": "view_000.png", "T_world_camera": [[...4x4...]]}, ...]}

``images`` may also be a mapping ``name -> 4x4``; ``"file"`` is accepted for ``"name"``, and an
image whose ``T_world_camera`` is null has no known pose.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from artrecon.errors import InputError

log = logging.getLogger(__name__)

#: File name endings read as images (case-insensitive).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: Fewest images SfM can work with at all; a ring around an object wants 20 or more.
MIN_IMAGES = 5


@dataclass(frozen=True)
class ImageSet:
    """A checked folder of images of one configuration.

    Attributes
    ----------
    root : Path
        The folder the user named (capture folder or image folder).
    image_dir : Path
        The folder holding the image files.
    names : list of str
        Image file names, sorted (the capture order when names are zero-padded).
    size : (width, height)
        Common image size in pixels.
    cameras_file : Path or None
        ``cameras.json`` of a capture, if present.
    """

    root: Path
    image_dir: Path
    names: list[str]
    size: tuple[int, int]
    cameras_file: Path | None


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in OpenCV convention.

    Attributes
    ----------
    K : (3, 3) float
        Camera matrix (fx, fy, cx, cy in pixels; pixel centres at integer coordinates).
    size : (width, height) or None
        Image size the matrix belongs to, if known.
    """

    K: np.ndarray
    size: tuple[int, int] | None = None

    def __post_init__(self):
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3):
            raise ValueError(f"intrinsics K: expected shape (3, 3), got {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"intrinsics K: focal lengths must be positive, got {K[0, 0]}, "
                             f"{K[1, 1]}")
        object.__setattr__(self, "K", K)

    @property
    def params(self) -> list[float]:
        """COLMAP PINHOLE parameters ``[fx, fy, cx, cy]`` (COLMAP also centres pixels at 0.5)."""
        K = self.K
        # COLMAP's image coordinates put the centre of the top-left pixel at (0.5, 0.5).
        return [K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5]


def load_image_folder(path: str | Path, min_images: int = MIN_IMAGES) -> ImageSet:
    """Find and check the images of one configuration.

    Parameters
    ----------
    path : str or Path
        A folder of images, or a capture folder holding ``images/``.
    min_images : int
        Fewest images accepted.

    Returns
    -------
    ImageSet

    Raises
    ------
    InputError
        The folder is missing, holds no or too few images, an image cannot be read, or the images
        differ in size.
    """
    root = Path(path)
    if not root.exists():
        raise InputError(f"image folder {root} does not exist: pass a folder of photos of one "
                         "configuration (or a capture folder with images/ inside)")
    if not root.is_dir():
        raise InputError(f"{root} is a file, not a folder: pass the folder holding the images")
    image_dir = root / "images" if (root / "images").is_dir() else root
    names = sorted(p.name for p in image_dir.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise InputError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {image_dir}: pass a folder "
                         "of photos of one configuration")
    if len(names) < min_images:
        raise InputError(f"only {len(names)} image(s) in {image_dir}; structure from motion needs "
                         f"at least {min_images} (a ring of 20-40 overlapping views works well)")
    size = None
    first = None
    for name in names:
        img = cv2.imread(str(image_dir / name), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"cannot read image {image_dir / name}: the file is corrupt or not an "
                             "image; remove or replace it")
        this = (int(img.shape[1]), int(img.shape[0]))
        if size is None:
            size, first = this, name
        elif this != size:
            raise InputError(f"images in {image_dir} differ in size: {first} is {size[0]}x{size[1]}"
                             f" but {name} is {this[0]}x{this[1]}; use one camera and one "
                             "resolution per image set")
    cameras = root / "cameras.json"
    return ImageSet(root, image_dir, names, size, cameras if cameras.is_file() else None)


def parse_intrinsics(value, size: tuple[int, int] | None = None) -> Intrinsics:
    """Intrinsics from a (3, 3) matrix, an ``"fx,fy,cx,cy"`` string, an :class:`Intrinsics`, or
    the path of a JSON file holding ``K`` (e.g. a capture's ``cameras.json``)."""
    if isinstance(value, Intrinsics):
        return value
    if isinstance(value, (str, Path)) and Path(value).is_file():
        try:
            data = json.loads(Path(value).read_text())
            K = np.asarray(data["K"], dtype=float)
        except (ValueError, KeyError, TypeError) as exc:
            raise InputError(f"cannot read intrinsics from {value}: expected JSON with a 3x3 'K' "
                             f"({exc})") from exc
        wh = (int(data["width"]), int(data["height"])) if "width" in data else size
        return Intrinsics(K, wh)
    if isinstance(value, str):
        try:
            fx, fy, cx, cy = (float(v) for v in value.split(","))
        except ValueError as exc:
            raise InputError(f"intrinsics {value!r}: expected 'fx,fy,cx,cy' in pixels or a JSON "
                             "file with 'K'") from exc
        return Intrinsics(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), size)
    K = np.asarray(value, dtype=float)
    if K.shape != (3, 3):
        raise ValueError(f"intrinsics: expected a (3, 3) matrix, got shape {K.shape}")
    return Intrinsics(K, size)


def load_cameras_json(path: str | Path) -> tuple[Intrinsics, dict[str, np.ndarray]]:
    """Read a capture's ``cameras.json``.

    Returns
    -------
    intrinsics : Intrinsics
    T_world_camera : dict of str to (4, 4) float
        Camera pose per image name (OpenCV convention); images without a known pose are absent.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read camera file {path}: {exc}") from exc
    if "K" not in data or "images" not in data:
        raise InputError(f"camera file {path} needs keys 'K' and 'images', has {sorted(data)}")
    intr = parse_intrinsics(data["K"], (int(data["width"]), int(data["height"]))
                            if "width" in data and "height" in data else None)
    items = data["images"]
    if isinstance(items, dict):
        items = [{"name": k, "T_world_camera": v} for k, v in items.items()]
    poses = {}
    for i, item in enumerate(items):
        name = item.get("name") or item.get("file")
        if name is not None and item.get("T_world_camera") is None:
            continue  # pose unknown for this image (e.g. a view the arm could not reach)
        T = np.asarray(item.get("T_world_camera"), dtype=float)
        if name is None or T.shape != (4, 4):
            raise InputError(f"camera file {path}: entry {i} needs 'name' and a 4x4 "
                             f"'T_world_camera' (got shape {T.shape})")
        poses[Path(name).name] = T
    return intr, poses
