"""Output of every command: folders written whole or not at all, and the file writers.

- Output folders: :func:`check_output_path` / :func:`check_output_dir` refuse an output that is,
  holds or lies inside an input, or replaces what this command did not write;
  :func:`make_work_dir` + :func:`publish_dir` put a complete result in place by renaming
  (:func:`work_dir` holds the work folder for a block and removes it when the block ends
  unpublished), and :func:`remove_stale_work_dirs` clears what killed runs left.
- Files: JSON, text, bytes and PLY written atomically (a temporary file beside the target,
  renamed over it), :class:`StagedFiles` / :func:`write_files_atomic` for several files at once;
  :func:`read_ply`, :func:`read_json`.
"""

from __future__ import annotations

import contextlib
import filecmp
import json
import logging
import os
import re
import shutil
import tempfile
import uuid
from glob import escape as glob_escape
from pathlib import Path

import numpy as np

from artrecon.errors import InputError

log = logging.getLogger(__name__)

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


@contextlib.contextmanager
def work_dir(out_dir: str | Path):
    """The work folder of a run writing ``out_dir`` (:func:`make_work_dir`) for the ``with``
    block, removed when the block ends without publishing it (an error, Ctrl-C).

    Removed wherever the interrupt lands, even inside :func:`make_work_dir` after the folder was
    made and before its name reached the caller (a busy machine can pause a process there, and a
    Ctrl-C then left the folder behind): every work folder of ``out_dir`` named with this
    process's id goes. A published folder has been renamed and is not touched.
    """
    out_dir = Path(out_dir)
    try:
        yield make_work_dir(out_dir)
    finally:
        own = _WORK_PREFIX.format(name=out_dir.name) + f"{os.getpid()}-"
        for p in out_dir.parent.glob(glob_escape(own) + "*"):
            shutil.rmtree(p, ignore_errors=True)


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
                     marker: str | tuple[str, ...] | None = None, flag: str = "--out",
                     example: str | Path | None = None) -> Path:
    """Check a folder a command will create (or, with ``overwrite``, replace whole).

    :func:`check_output_path` first; then an existing ``out_dir`` is refused when it is a file
    (never replaced by a folder), when ``overwrite`` is not given, or when it is a non-empty
    folder without ``marker`` (a file every result of this command holds, e.g. ``model.json``;
    several: any one of them): ``--overwrite`` replaces only a result of the same command, never
    a folder of other files.

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
        markers = (marker,) if isinstance(marker, str) else tuple(marker or ())
        if (markers and any(out_dir.iterdir())
                and not any((out_dir / m).exists() for m in markers)):
            raise InputError(f"{flag} {out_dir} is a folder that holds no "
                             f"{' or '.join(markers)}, so no result of this command; "
                             "--overwrite replaces only such results (whole), never other "
                             f"files: choose a new folder for {flag}")
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


#: Lists of at least this many items that hold only numbers (or lists of numbers) are written
#: on one line by :func:`json_dumps` (a link's points, colours, normals).
LONG_LIST = 16


def json_dumps(obj, indent: int = 1) -> str:
    """``json.dumps(obj, indent=indent)``, the same JSON value, with every long list of numbers
    (or of lists of numbers: point rows) on one line: readable where it is read (joints,
    metadata), and written by the C encoder where it is large. With ``indent`` the json module
    encodes in Python, one number per line: a model of 30k points took 0.78 s and 7.7 MB,
    most of it newlines."""
    token = uuid.uuid4().hex  # the placeholders' prefix: no string of ``obj`` holds it
    compact: list[str] = []

    numbers = {int, float}  # exact types: no bools, no subclasses the encoder would treat apart

    def long_numbers(o) -> bool:
        if len(o) < LONG_LIST:
            return False
        if all(type(x) in numbers for x in o):
            return True
        return (all(type(x) in (list, tuple) for x in o)
                and all(type(y) in numbers for x in o for y in x))

    def swap(o):
        if isinstance(o, dict):
            return {k: swap(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            if long_numbers(o):
                compact.append(json.dumps(o, separators=(", ", ": ")))
                return f"{token}:{len(compact) - 1}"
            return [swap(v) for v in o]
        return o

    text = json.dumps(swap(obj), indent=indent)
    return re.sub(f'"{token}:(\\d+)"', lambda m: compact[int(m.group(1))], text)


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
