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

import filecmp
import hashlib
import json
import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from glob import escape as glob_escape
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
#: later, match-based check (artrecon.confidence.check_motion).
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


#: Work folders of a run writing OUT are named ``.OUT.tmp-<pid>-<random>`` beside OUT.
_WORK_PREFIX = ".{name}.tmp-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_work_dirs(out_dir: str | Path) -> list[Path]:
    """Remove work folders of runs that wrote ``out_dir`` and died (killed, power cut).

    A run builds its output in ``.OUT.tmp-<pid>-...`` beside ``OUT`` and renames it when complete
    (see :func:`make_work_dir`, :func:`publish_dir`), so an interrupted run leaves only such a
    folder, never a half-written ``OUT``. Folders whose process is gone are removed; those of a
    live process (another run writing the same output now) are left alone.

    Returns
    -------
    list of Path
        The folders removed.
    """
    out_dir = Path(out_dir)
    removed = []
    if not out_dir.parent.is_dir():
        return removed
    prefix = _WORK_PREFIX.format(name=out_dir.name)
    for p in out_dir.parent.glob(prefix + "*"):
        head = p.name[len(prefix):].split("-", 1)[0]
        if p.is_dir() and head.isdigit() and not _alive(int(head)):
            shutil.rmtree(p, ignore_errors=True)
            removed.append(p)
            log.info("removed %s, left by an interrupted run", p)
    return removed


def make_work_dir(out_dir: str | Path) -> Path:
    """An empty work folder beside ``out_dir`` (same file system, so renaming it is atomic), after
    removing those left by interrupted runs."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_work_dirs(out_dir)
    prefix = _WORK_PREFIX.format(name=out_dir.name) + f"{os.getpid()}-"
    work = Path(tempfile.mkdtemp(prefix=prefix, dir=out_dir.parent))
    # mkdtemp makes 0700; the published folder gets the usual mode (as mkdir would give it)
    os.chmod(work, 0o777 & ~umask())
    return work


def check_output_path(out: str | Path, inputs, *, flag: str = "--out",
                      example: str | Path | None = None) -> Path:
    """Refuse an output path that is an input, contains one, or lies inside an input folder.

    Writing there would replace an input (``--overwrite`` replaces the output folder whole) or
    add files to it. Symbolic links are followed.

    Parameters
    ----------
    out : path
        The output file or folder.
    inputs : iterable of path
        Input files and folders (image folders, a scene file and the files it references...).
    flag : str
        How the user named ``out`` (for the message).
    example : path, optional
        An output path to suggest.

    Returns
    -------
    Path
        ``out``, absolute.

    Raises
    ------
    InputError
        Naming the input and what to do.
    """
    out = Path(out)
    out_r = out.resolve()
    inputs = [(Path(p), Path(p).resolve()) for p in inputs]
    # the most specific finding first: equal to an input, then around one, then inside one
    problem = next((f"is the input {p}" for p, r in inputs if out_r == r), None)
    problem = problem or next((f"contains the input {p}" for p, r in inputs
                               if r.is_relative_to(out_r)), None)
    problem = problem or next((f"lies inside the input folder {p}" for p, r in inputs
                               if out_r.is_relative_to(r) and r.is_dir()), None)
    if problem is not None:
        hint = f", e.g. {flag} {example}" if example is not None else ""
        raise InputError(f"{flag} {out} {problem}: writing the result there would replace or "
                         f"change an input, so nothing was done. Choose a path outside the "
                         f"inputs{hint}")
    return out_r


def check_output_dir(out_dir: str | Path, inputs=(), *, overwrite: bool = False,
                     marker: str | None = None, flag: str = "--out",
                     example: str | Path | None = None) -> Path:
    """Check a folder a command will create (or, with ``overwrite``, replace whole).

    :func:`check_output_path` first; then an existing ``out_dir`` is refused when it is a file
    (never replaced by a folder), when ``overwrite`` is not given, or when it is a non-empty
    folder without ``marker`` (a file every result of this command holds, e.g. ``model.json``):
    ``--overwrite`` replaces only a result of the same command, never a folder of other files.

    Returns
    -------
    Path
        ``out_dir`` (as given).

    Raises
    ------
    InputError
    """
    out_dir = Path(out_dir)
    check_output_path(out_dir, inputs, flag=flag, example=example)
    if out_dir.is_symlink() or (out_dir.exists() and not out_dir.is_dir()):
        kind = "a symbolic link" if out_dir.is_symlink() else "a file"
        raise InputError(f"{flag} {out_dir} is {kind}, not a folder; the output is a folder: "
                         f"name a new one (a file is never replaced)")
    above = next((p for p in out_dir.absolute().parents if p.exists() or p.is_symlink()), None)
    if above is not None and not above.is_dir():
        raise InputError(f"{flag} {out_dir} cannot be made: {above} is a file, not a folder; "
                         f"nothing was written. Choose a {flag} inside a folder")
    if out_dir.exists():
        if not overwrite:
            raise InputError(f"output folder {out_dir} exists; choose another {flag} or pass "
                             "--overwrite (overwrite=True) to replace it")
        if marker is not None and any(out_dir.iterdir()) and not (out_dir / marker).exists():
            raise InputError(f"{flag} {out_dir} is a folder that holds no {marker}, so no result "
                             f"of this command; --overwrite replaces only such results (whole), "
                             f"never other files: choose a new folder for {flag}")
    return out_dir


def publish_dir(work: str | Path, out_dir: str | Path) -> Path:
    """Put a complete work folder in place of ``out_dir`` by renaming.

    An existing ``out_dir`` is first renamed aside (into a work-folder name, removed afterwards),
    so at every instant ``out_dir`` is either the old complete result, absent, or the new complete
    result.
    """
    work, out_dir = Path(work), Path(out_dir)
    old = None
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=_WORK_PREFIX.format(name=out_dir.name)
                                    + f"{os.getpid()}-old-", dir=out_dir.parent))
        os.replace(out_dir, old / "previous")
    os.replace(work, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return out_dir


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


# ---------------------------------------------------------------------------- writing files
# The one copy of the project's file writers: whole or not at all (a temporary file beside the
# target, renamed over it when complete: a run killed while writing leaves the old file, or none,
# never half of one), with the usual file mode (mkstemp makes 0600).


def umask() -> int:
    """The process's file-creation mask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _temporary_beside(path: Path, data: bytes) -> Path:
    """``data`` in a new hidden file ``.NAME.<pid>-<random>.tmp`` beside ``path`` (its folder
    created), with the usual file mode; such files that a killed process left behind are
    removed first."""
    path.parent.mkdir(parents=True, exist_ok=True)
    for old in path.parent.glob(f".{glob_escape(path.name)}.*.tmp"):
        head = old.name[len(path.name) + 2:].split("-", 1)[0]
        if head.isdigit() and not _alive(int(head)):
            old.unlink(missing_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=".tmp",
                               dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes 0600; give the usual mode
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(tmp)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all; returns the path."""
    path = Path(path)
    tmp = _temporary_beside(path, data)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all; returns the path."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_json_atomic(path: str | os.PathLike, obj, indent: int | None = 2) -> Path:
    """Write ``obj`` as JSON (numpy values and paths converted; NaN refused) whole or not at
    all; returns the path."""
    text = json.dumps(obj, indent=indent, allow_nan=False, default=_json_default)
    return write_text_atomic(path, text + "\n")


class StagedFiles:
    """Several files written together, each whole or not at all.

    :meth:`write` puts each file's bytes in a temporary file beside its target; :meth:`commit`
    first checks every target (none may be a protected input; none may exist unless
    ``overwrite``), then renames the temporaries into place in the order written (so the file
    that names the others goes last, and never names a missing one); :meth:`abort` removes the
    temporaries. An interrupted write (an exception, Ctrl-C, a kill) leaves the old files and at
    most hidden ``.NAME.*.tmp`` temporaries, never half of a file under its name.

    Parameters
    ----------
    overwrite : bool
        Replace existing targets. When False, :meth:`commit` raises InputError naming them.
    protect : iterable of path
        Inputs that must never be written over (e.g. the model file being exported).
    """

    def __init__(self, overwrite: bool = True, protect=()) -> None:
        self.overwrite = overwrite
        self.protect = [Path(p) for p in protect]
        self._pending: list[tuple[Path, Path]] = []

    def write(self, path: str | os.PathLike, data: bytes) -> None:
        """Stage ``data`` for ``path`` (its folder is created now)."""
        path = Path(path)
        self._pending.append((_temporary_beside(path, data), path))

    def targets(self) -> list[Path]:
        """The files staged so far, in the order they will be put in place."""
        return [path for _, path in self._pending]

    def check(self) -> None:
        """InputError if a target is a protected input, a folder, or (without ``overwrite``)
        an existing file with other contents."""
        for path in self.targets():
            for p in self.protect:
                if path.resolve() == p.resolve() or (path.exists() and p.exists()
                                                     and os.path.samefile(path, p)):
                    raise InputError(f"{path} is the input {p}; writing it would destroy the "
                                     "input. Choose another output path")
            if path.is_dir():
                raise InputError(f"{path} is a folder, where a file would be written; name "
                                 "another output path")
        # a file that already holds exactly these bytes is not replaced by anything new (e.g. the
        # meshes an MJCF and a URDF export of one twin share)
        existing = [path for tmp, path in self._pending
                    if path.exists() and not filecmp.cmp(tmp, path, shallow=False)]
        if existing and not self.overwrite:
            more = f" and {len(existing) - 1} more" if len(existing) > 1 else ""
            raise InputError(f"{existing[0]}{more} exist(s) already; nothing was written. "
                             "Choose another output path, or pass --overwrite to replace them")

    def commit(self) -> list[Path]:
        """Check the targets (:meth:`check`), then rename every staged file into place;
        returns the paths in order. On any failure the temporaries not yet renamed are
        removed."""
        try:
            self.check()
            done = []
            for tmp, path in self._pending:  # in order of writing: the main file last
                os.replace(tmp, path)
                done.append(path)
        except BaseException:
            self.abort()
            raise
        self._pending = []
        return done

    def abort(self) -> None:
        """Remove the staged temporaries (the targets are untouched)."""
        for tmp, _ in self._pending:
            tmp.unlink(missing_ok=True)
        self._pending = []



def write_files_atomic(files, *, overwrite: bool = True, protect=()) -> list[Path]:
    """Write several files together, whole or not at all (:class:`StagedFiles`).

    Parameters
    ----------
    files : iterable of (path, bytes)
        In order; the last is put in place last. A generator may compute each file's bytes
        when asked: an exception in it (or Ctrl-C) leaves every target as it was.
    overwrite : bool
        Replace existing files (else InputError, nothing written).
    protect : iterable of path
        Inputs that must never be written over.

    Returns
    -------
    list of Path
        The files written, in order.
    """
    staged = StagedFiles(overwrite, protect)
    try:
        for path, data in files:
            staged.write(path, data)
    except BaseException:
        staged.abort()
        raise
    return staged.commit()


_PLY_TYPES = {"<f4": "float", "<f8": "double", "u1": "uchar"}


def ply_bytes(points: np.ndarray, normals: np.ndarray | None = None,
              colours: np.ndarray | None = None, precision: str = "float") -> bytes:
    """A binary little-endian PLY of points with optional normals and RGB colours.

    Parameters
    ----------
    points : (n, 3) float
    normals : (n, 3) float, optional
    colours : (n, 3) uint8, optional
    precision : {"float", "double"}
        Coordinates and normals as 32-bit (the reconstruction's folders) or 64-bit floats
        (exported twins, exact to the last bit).

    Returns
    -------
    bytes
        Header and vertex records: x y z [nx ny nz] [red green blue].
    """
    if precision not in ("float", "double"):
        raise ValueError(f"precision must be 'float' or 'double', got {precision!r}")
    kind = "<f4" if precision == "float" else "<f8"
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {points.shape}")
    n = len(points)
    columns = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
    fields = [("x", kind), ("y", kind), ("z", kind)]
    for names, values, vkind in ((("nx", "ny", "nz"), normals, kind),
                                 (("red", "green", "blue"), colours, "u1")):
        if values is None:
            continue
        values = np.asarray(values)
        if values.shape != (n, 3):
            raise ValueError(f"{names}: expected shape ({n}, 3), got {values.shape}")
        fields += [(c, vkind) for c in names]
        columns.update({c: values[:, k] for k, c in enumerate(names)})
    rec = np.zeros(n, dtype=fields)
    for name, _ in fields:
        rec[name] = columns[name]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property {_PLY_TYPES[t]} {name}" for name, t in fields]
    header.append("end_header")
    return ("\n".join(header) + "\n").encode("ascii") + rec.tobytes()


def write_ply(path: str | Path, points: np.ndarray, normals: np.ndarray | None = None,
              colours: np.ndarray | None = None) -> Path:
    """Binary little-endian PLY of points (n, 3) with optional normals (n, 3) and RGB (n, 3)
    (32-bit floats, :func:`ply_bytes`), written whole or not at all."""
    return write_bytes_atomic(path, ply_bytes(points, normals, colours))


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Points (n, 3), normals (n, 3) or None, colours (n, 3) uint8 or None of a PLY written by
    :func:`write_ply` (binary little-endian vertex lists of float and uchar properties)."""
    data = Path(path).read_bytes()
    if b"end_header\n" not in data or not data.startswith(b"ply"):
        raise InputError(f"{path} is not a PLY file written by artrecon (no PLY header)")
    head, body = data.split(b"end_header\n", 1)
    if b"binary_little_endian" not in head:
        raise InputError(f"{path}: only binary little-endian PLY files are read")
    props = [ln.split() for ln in head.splitlines() if ln.startswith(b"property")]
    kinds = {b"float": "<f4", b"uchar": "u1", b"double": "<f8"}
    if any(len(p) != 3 or p[1] not in kinds for p in props):
        raise InputError(f"{path}: unsupported PLY properties (float, double and uchar only)")
    dtype = [(p[2].decode(), kinds[p[1]]) for p in props]
    rec = np.frombuffer(body, dtype=dtype)
    names = [d[0] for d in dtype]

    def cols(wanted, out_dtype):
        return (np.column_stack([rec[c] for c in wanted]).astype(out_dtype)
                if all(c in names for c in wanted) else None)

    points = cols(("x", "y", "z"), float)
    if points is None:
        raise InputError(f"{path}: the PLY has no x, y, z properties")
    return points, cols(("nx", "ny", "nz"), float), cols(("red", "green", "blue"), np.uint8)


def read_json(path: str | Path):
    """The JSON document in ``path``; InputError naming the file when it is missing or not JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path} is not valid JSON ({exc})") from exc
