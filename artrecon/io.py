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

Optionally, where the object is, in the same world frame as the poses::

    "region": {"points": [[x, y, z], ...], "source": "..."}

points whose convex hull holds the object (``sim.capture`` writes the convex hull of the visual
hull its survey carved from the robot's own photographs; a bounding box's eight corners will do).
With the poses held fixed, SfM then extracts features only where the region projects into each
image (:func:`artrecon.sfm.extraction.region_boxes`): the table and room around the object cost
most of the extraction and matching and tell a reconstruction from known poses nothing.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from artrecon.errors import InputError

log = logging.getLogger(__name__)

#: File name endings read as images (case-insensitive).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
#: Fewest images SfM can work with at all; a ring around an object wants 20 or more.
MIN_IMAGES = 5
#: Width (pixels) of the grey thumbnails compared to find near-identical images. At 64 px each
#: thumbnail pixel averages a 10 x 10 block of a 640 x 480 image: re-encoding noise (JPEG at
#: quality 90: under 2 grey levels) averages out, while a part that moves by a few pixels in the
#: image still changes the thumbnail pixels along its edges by tens of levels.
THUMBNAIL_WIDTH = 64
#: Two images are near-identical when no thumbnail pixel differs by more than this many grey
#: levels (of 255). The test is strict on purpose (the largest difference, not a mean): it only
#: decides whether the user is told at once that nothing moved; sets that pass it still meet the
#: later, match-based check (artrecon.diagnosis.check_motion).
NEAR_IDENTICAL_LEVELS = 6.0
#: B is "A again" when at least this share of its images has a near-identical image in A (or
#: the other way round).
NEAR_IDENTICAL_SHARE = 0.9


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
    region : (k, 3) float or None
        Points whose convex hull holds the object, in the camera poses' world frame
        (``cameras.json``'s ``region``, :func:`load_region`); set only when the set's own poses
        are used (see :func:`artrecon.reconstruct.reconstruct`), else None.
    digests : tuple of str
        SHA-1 of each image file's bytes, in the order of ``names`` (to tell identical image sets
        apart from merely similar ones).
    thumbnails : tuple of (h, THUMBNAIL_WIDTH) float32
        Each image in grey, shrunk by pixel-area averaging (to find near-identical images:
        re-encoded copies, the same view photographed again).
    """

    root: Path
    image_dir: Path
    names: list[str]
    size: tuple[int, int]
    cameras_file: Path | None
    digests: tuple[str, ...] = ()
    thumbnails: tuple = field(default=(), compare=False, repr=False)
    region: np.ndarray | None = field(default=None, compare=False, repr=False)


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
            raise InputError(f"intrinsics K: expected shape (3, 3), got {K.shape}")
        if not np.all(np.isfinite(K)):
            raise InputError(f"intrinsics K: every entry must be a finite number, got "
                             f"{K.tolist()}")
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
    digests, thumbnails = [], []
    for name in names:
        try:
            data = (image_dir / name).read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read image {image_dir / name}: {exc.strerror or exc}; check "
                             "its permissions, or remove it") from exc
        digests.append(hashlib.sha1(data).hexdigest())
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED) if data else None
        if img is None:
            raise InputError(f"cannot read image {image_dir / name}: the file is corrupt or not an "
                             "image; remove or replace it")
        thumbnails.append(_thumbnail(img))
        this = (int(img.shape[1]), int(img.shape[0]))
        if size is None:
            size, first = this, name
        elif this != size:
            raise InputError(f"images in {image_dir} differ in size: {first} is {size[0]}x{size[1]}"
                             f" but {name} is {this[0]}x{this[1]}; use one camera and one "
                             "resolution per image set")
    cameras = root / "cameras.json"
    return ImageSet(root, image_dir, names, size, cameras if cameras.is_file() else None,
                    tuple(digests), tuple(thumbnails))


def image_set_again(images: ImageSet, min_images: int = MIN_IMAGES) -> ImageSet:
    """An image set checked earlier (:func:`load_image_folder`), as that function would give it
    now: ``images`` itself when its folder holds the same image files with the same bytes (the
    SHA-1 of each file is compared; no image is decoded again), else the folder loaded anew
    (and checked: the errors are :func:`load_image_folder`'s).

    For a caller that loaded the set in another step of the same run (another process, say):
    decoding every image again costs about 5 ms per 640 x 480 PNG, hashing it a tenth of that.
    """
    image_dir = Path(images.image_dir)
    try:
        names = sorted(p.name for p in image_dir.iterdir()
                       if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        same = (names == list(images.names) and len(images.digests) == len(names)
                and len(images.thumbnails) == len(names)
                and all(hashlib.sha1((image_dir / n).read_bytes()).hexdigest() == d
                        for n, d in zip(names, images.digests, strict=True)))
    except OSError:
        same = False
    # load_image_folder's sets hold no region (the caller adds it from its poses' file)
    return replace(images, region=None) if same else load_image_folder(images.root, min_images)


def _thumbnail(img: np.ndarray) -> np.ndarray:
    """(h, THUMBNAIL_WIDTH) float32 grey thumbnail of an image (any channels and depth)."""
    if img.dtype != np.uint8:  # 16-bit or float images: to 0-255
        img = cv2.normalize(img.astype(np.float32), None, 0, 255, cv2.NORM_MINMAX)
    if img.ndim == 3:
        img = cv2.cvtColor(np.ascontiguousarray(img[:, :, :3]).astype(np.float32),
                           cv2.COLOR_BGR2GRAY)
    h = max(1, round(THUMBNAIL_WIDTH * img.shape[0] / img.shape[1]))
    return cv2.resize(img.astype(np.float32), (THUMBNAIL_WIDTH, h), interpolation=cv2.INTER_AREA)


def near_twins(set_a: ImageSet, set_b: ImageSet) -> list[tuple[str, str, float]]:
    """For each image of B, its most similar image of A when the two are near-identical
    (:data:`NEAR_IDENTICAL_LEVELS`).

    Returns
    -------
    list of (name_b, name_a, levels)
        ``levels``: the largest grey-level difference of their thumbnails.
    """
    if not set_a.thumbnails or not set_b.thumbnails:
        return []
    ta = np.stack(set_a.thumbnails)
    out = []
    for name, tb in zip(set_b.names, set_b.thumbnails, strict=True):
        if tb.shape != ta.shape[1:]:
            return []  # other image sizes: not copies
        levels = np.abs(ta - tb[None]).reshape(len(ta), -1).max(axis=1)
        k = int(np.argmin(levels))
        if levels[k] <= NEAR_IDENTICAL_LEVELS:
            out.append((name, set_a.names[k], float(levels[k])))
    return out


def check_distinct(set_a: ImageSet, set_b: ImageSet) -> None:
    """Refuse two image sets that are the same photos: the object cannot have moved between them.

    Raises
    ------
    InputError
        Both name the same folder, every image of one set is byte-identical to an image of the
        other, or nearly every image of one set looks the same as an image of the other
        (:func:`near_twins`: re-encoded copies, the same views photographed again).
    """
    same_dir = set_a.image_dir.resolve() == set_b.image_dir.resolve()
    da, db = set(set_a.digests), set(set_b.digests)
    if same_dir or (da and db and (da <= db or db <= da)):
        what = (f"both name the folder {set_a.image_dir}" if same_dir else
                f"every image of {set_a.image_dir if da <= db else set_b.image_dir} is also in "
                f"{set_b.image_dir if da <= db else set_a.image_dir} (byte for byte)")
        raise InputError(f"configuration A and B are the same images ({what}): the object did not "
                         "move between them. Photograph configuration B after moving a joint of "
                         "the object (open the lid, pull the drawer), and pass that folder as B")
    for first, second in ((set_a, set_b), (set_b, set_a)):
        twins = near_twins(first, second)
        if twins and len(twins) >= NEAR_IDENTICAL_SHARE * len(second.names):
            b, a, levels = max(twins, key=lambda t: t[2])
            raise InputError(
                f"nothing moved between A and B: {len(twins)} of the {len(second.names)} images "
                f"of {second.image_dir} look the same as images of {first.image_dir} (e.g. {b} "
                f"and {a}: no pixel differs by more than {levels:.0f} grey levels of 255 at "
                f"{THUMBNAIL_WIDTH} px wide): the same object in the same configuration, from the "
                "same views (or a re-encoded copy). Photograph configuration B after moving a "
                "joint of the object (open the lid, pull the drawer), and pass that folder as B")
    shared = len(da & db)
    if shared:
        log.warning("%d image(s) of %s and %s are byte-identical; configuration B should show "
                    "the object moved", shared, set_a.image_dir, set_b.image_dir)


def parse_intrinsics(value, size: tuple[int, int] | None = None) -> Intrinsics:
    """Intrinsics from a (3, 3) matrix, an ``"fx,fy,cx,cy"`` string, an :class:`Intrinsics`, or
    the path of a JSON file holding ``K`` (e.g. a capture's ``cameras.json``)."""
    if isinstance(value, Intrinsics):
        return value
    if isinstance(value, (str, Path)) and Path(value).is_file():
        try:
            data = json.loads(Path(value).read_text())
            K = np.asarray(data["K"], dtype=float)
        except KeyError as exc:
            raise InputError(f"cannot read intrinsics from {value}: expected JSON with a 3x3 'K' "
                             f"(it has no {exc})") from exc
        except (ValueError, TypeError) as exc:
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
    try:
        K = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:  # ragged rows, text
        raise InputError(f"intrinsics 'K' must be a 3x3 matrix of numbers (three rows of three), "
                         f"got {str(value)[:80]}") from exc
    if K.shape != (3, 3):
        raise InputError(f"intrinsics: expected a (3, 3) matrix, 'fx,fy,cx,cy' or a JSON file "
                         f"with 'K', got shape {K.shape}")
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
    try:
        return _parse_cameras(data, path)
    except InputError as exc:
        if str(path) in str(exc):
            raise
        raise InputError(f"camera file {path}: {exc}") from exc
    except (TypeError, ValueError, AttributeError, KeyError, IndexError) as exc:
        raise InputError(f"camera file {path} is malformed ({type(exc).__name__}: {exc}); "
                         "expected {\"K\": 3x3, \"width\": W, \"height\": H, \"images\": "
                         "[{\"name\": ..., \"T_world_camera\": 4x4}, ...]} (see "
                         "artrecon.io)") from exc


def load_region(path: str | Path) -> np.ndarray | None:
    """The ``region`` of a capture's ``cameras.json`` (see the module docstring): (k, 3) points
    whose convex hull holds the object, in the poses' world frame; None when the file has none.

    Raises
    ------
    InputError
        The file cannot be read, or its region is not at least four finite 3D points.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read camera file {path}: {exc}") from exc
    region = data.get("region") if isinstance(data, dict) else None
    if region is None:
        return None
    try:
        points = np.asarray(region["points"], dtype=float)
    except (TypeError, ValueError, KeyError) as exc:
        raise InputError(f"camera file {path}: 'region' must be {{\"points\": [[x, y, z], ...]}} "
                         f"({type(exc).__name__}: {exc}); fix it or remove the region (features "
                         "are then extracted from the whole images)") from exc
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 4 \
            or not np.all(np.isfinite(points)):
        raise InputError(f"camera file {path}: 'region' needs at least four finite 3D points "
                         f"(got an array of shape {points.shape}); fix it or remove the region")
    return points


def _parse_cameras(data, path: Path) -> tuple[Intrinsics, dict[str, np.ndarray]]:
    if not isinstance(data, dict):
        raise InputError(f"camera file {path} holds a JSON {type(data).__name__}; expected an "
                         "object with keys 'K' and 'images'")
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
        try:
            T = np.asarray(item.get("T_world_camera"), dtype=float)
        except (TypeError, ValueError):
            T = np.zeros(0)
        if name is None or T.shape != (4, 4):
            raise InputError(f"camera file {path}: entry {i} needs 'name' and a 4x4 "
                             f"'T_world_camera' (got shape {T.shape})")
        if not np.all(np.isfinite(T)):
            raise InputError(f"camera file {path}: entry {i} ({name}): 'T_world_camera' holds "
                             "a value that is not a finite number; fix or remove the entry")
        poses[Path(name).name] = T
    return intr, poses
