"""Stage cache of the evaluation: results stored under the hash of everything they depend on.

A stage (a capture, a reconstruction, a manipulation) is a function of its inputs: the scene file
and every file it includes or references, the configuration, the number of views, the seed, the
stage's own settings, the package version and the source code of the modules that compute it.
:func:`stage_key` hashes a JSON description of those inputs; :func:`cached_stage` keeps the
stage's output folder at ``ROOT/<stage>-<hash>/`` and builds it only when it is absent, so a second
run of ``python -m sim.evaluate`` redoes only what changed. Folders are built under a temporary
name beside their final place and renamed when complete: a folder that exists is whole (a run that
is killed leaves at most a work folder ``.<stage>-<hash>.tmp-<pid>-*``, which the next run ignores
and removes; one whose process still runs, a concurrent run on the same folder, is left alone).

Several processes may share one cache (the workers of a sweep, :mod:`sim.evaluate.sweep`): a
complete folder is never removed or written again, so a reader never sees half of one; a process
about to build a stage takes an exclusive lock on ``ROOT/.<stage>-<hash>.lock`` (``flock``: the
kernel releases it when the holder dies; the holder removes the file when done) and looks
again, so a second process asking for the same stage waits for the first and reads its folder
instead of building it twice.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import importlib.util
import json
import logging
import os
import re
import shutil
import time
from collections.abc import Callable, Iterable
from pathlib import Path

from artrecon.files import make_work_dir, write_json_atomic  # noqa: F401 (cache.write_json_atomic)

log = logging.getLogger(__name__)

#: Hex digits of the hash kept in folder names: 16 (64 bits) make a collision between the few
#: hundred stage results of one evaluation folder practically impossible.
KEY_LENGTH = 16
#: File written last into a stage folder, with the stage's own metadata (timings, inputs).
STAGE_FILE = "stage.json"

_FILE_ATTR = re.compile(r"""\bfile\s*=\s*["']([^"']+)["']""")
_DIR_ATTR = re.compile(r"""\b(meshdir|texturedir|assetdir)\s*=\s*["']([^"']+)["']""")


def hash_bytes(*chunks: bytes) -> str:
    """SHA-256 hex digest of the concatenated chunks."""
    h = hashlib.sha256()
    for c in chunks:
        h.update(c)
    return h.hexdigest()


def hash_files(paths: Iterable[str | os.PathLike], root: str | os.PathLike | None = None) -> str:
    """SHA-256 over the names (relative to ``root`` if given) and contents of files, in the given
    order. A missing file contributes its name and the word ``missing``."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        name = os.path.relpath(p, root) if root is not None else str(p)
        h.update(name.encode() + b"\0")
        h.update(p.read_bytes() if p.is_file() else b"missing")
        h.update(b"\0")
    return h.hexdigest()


def scene_files(scene_path: str | os.PathLike) -> list[Path]:
    """The scene file and every file it depends on, found by reading the XML.

    Every ``file="..."`` attribute (``<include>``, meshes, textures, ``<model>`` of an
    ``<attach>``) is resolved the way MuJoCo does -- relative to the folder of the top-level
    file, under the ``meshdir``/``texturedir``/``assetdir`` given in the file that names it --
    and, failing that, relative to the folder of the file that names it. Included or attached
    XML files are read in turn. The list is sorted and has no duplicates; files that cannot be
    found are kept (their absence is part of the hash).

    Parameters
    ----------
    scene_path : path
        The scene's MJCF file.

    Returns
    -------
    files : list of pathlib.Path
    """
    top = Path(scene_path).resolve()
    seen: set[Path] = set()
    todo = [top]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        if path.suffix.lower() != ".xml" or not path.is_file():
            continue
        text = path.read_text(errors="replace")
        text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
        dirs = [d for _, d in _DIR_ATTR.findall(text)]
        for name in _FILE_ATTR.findall(text):
            candidates = [top.parent / d / name for d in dirs] + [top.parent / name,
                                                                  path.parent / name]
            found = next((c.resolve() for c in candidates if c.is_file()), None)
            todo.append(found if found is not None else (path.parent / name).resolve())
    return sorted(seen)


def scene_hash(scene_path: str | os.PathLike) -> str:
    """Hash of a scene file and every file it depends on (:func:`scene_files`)."""
    top = Path(scene_path).resolve()
    return hash_files(scene_files(top), root=top.parent)


def source_hash(modules: Iterable) -> str:
    """Hash of the source files of Python modules or packages (a package: every ``.py`` file
    under it), so that a change of the code that computes a stage invalidates its results."""
    files: list[Path] = []
    for m in modules:
        f = Path(m.__file__)
        if f.name == "__init__.py":
            files += sorted(f.parent.rglob("*.py"))
        else:
            files.append(f)
    return hash_files(files, root=Path(os.path.commonpath([str(f) for f in files])))


def _imported_modules(path: Path, package: str) -> set[str]:
    """Names of the ``package`` modules a source file imports (at any depth of the file:
    imports inside functions count)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.split(".")[0] == package}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                node.module.split(".")[0] == package:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}  # submodules by name
    return names


def module_closure(module, package: str | None = None) -> list[Path]:
    """Source files of ``module`` and of every module of its package it imports, directly or
    through others (read from the sources: an import inside a function counts too), sorted.

    A stage that runs only part of a package depends on that part alone: a cache keyed by
    :func:`source_hash` of the whole package would be rebuilt for an edit it never runs.
    Importing a package's ``__init__`` counts as importing that file only.
    """
    package = package or module.__name__.split(".")[0]
    seen: dict[str, Path] = {}
    todo = [module.__name__]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        try:
            spec = importlib.util.find_spec(name)
        except ModuleNotFoundError:  # a.b.c where a.b is a module: c is a name in it
            spec = None
        if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
            continue  # a name imported from a module (a function, a class), not a module
        seen[name] = Path(spec.origin)
        todo += sorted(_imported_modules(seen[name], package) - set(seen))
        parent = name.rpartition(".")[0]
        while parent and parent not in seen:  # importing a.b runs a/__init__.py first: its
            # text counts; what it re-exports for users is not code the module runs
            seen[parent] = Path(importlib.util.find_spec(parent).origin)
            parent = parent.rpartition(".")[0]
    return sorted(set(seen.values()))


def closure_hash(module, package: str | None = None) -> str:
    """:func:`hash_files` of :func:`module_closure`: changes when any code ``module`` can run
    changes, and only then."""
    files = module_closure(module, package)
    return hash_files(files, root=Path(os.path.commonpath([str(f) for f in files])))


def stage_key(stage: str, inputs: dict) -> str:
    """Cache key ``<stage>-<hash>`` of a stage's inputs (a JSON-serialisable dict)."""
    if not re.fullmatch(r"[A-Za-z0-9_.]+", stage):
        raise ValueError(f"stage name must be letters, digits, '_' or '.', got {stage!r}")
    text = json.dumps(inputs, sort_keys=True, default=str)
    return f"{stage}-{hash_bytes(text.encode())[:KEY_LENGTH]}"


def is_cached(root: str | os.PathLike, stage: str, inputs: dict) -> bool:
    """Whether :func:`cached_stage` would find a complete folder for these inputs."""
    return (Path(root) / stage_key(stage, inputs) / STAGE_FILE).is_file()


def cached_stage(root: str | os.PathLike, stage: str, inputs: dict,
                 build: Callable[[Path], dict]) -> tuple[Path, dict, bool]:
    """The output folder of a stage, built by ``build`` unless a complete one exists.

    Parameters
    ----------
    root : path
        Cache folder (``OUT/cache``).
    stage : str
        Stage name (``capture_a``, ``reconstruct``, ...).
    inputs : dict
        Everything the stage's result depends on (JSON-serialisable).
    build : callable
        ``build(folder) -> metadata``: writes the stage's files into the (empty, temporary)
        ``folder`` and returns a JSON-serialisable dict (e.g. timings), stored as ``stage.json``.

    Returns
    -------
    folder : pathlib.Path
        ``root/<stage>-<hash>``.
    metadata : dict
        ``build``'s dict plus ``inputs``, ``key`` and ``build_s`` (seconds ``build`` took).
    hit : bool
        True if the folder was already there (nothing was built).
    """
    root = Path(root)
    key = stage_key(stage, inputs)
    final = root / key
    meta_path = final / STAGE_FILE
    if meta_path.is_file():
        log.info("cache hit: %s", final)
        return final, json.loads(meta_path.read_text()), True
    root.mkdir(parents=True, exist_ok=True)
    with _stage_lock(root / f".{key}.lock"):
        if meta_path.is_file():  # another process built it while this one waited for the lock
            log.info("cache hit (built by a concurrent run): %s", final)
            return final, json.loads(meta_path.read_text()), True
        return _build(root, key, final, inputs, build)


@contextlib.contextmanager
def _stage_lock(path: Path):
    """Hold an exclusive ``flock`` on the lock file ``path`` while the block runs.

    The holder removes the file when it is done, so a cache keeps no lock files; a process that
    was waiting on the removed file finds, once it holds that lock, that ``path`` is no longer
    the file it locked, and starts over (the usual lock-file dance). A holder that dies releases
    the lock (the kernel does) and leaves the file, which the next holder removes. Without
    ``fcntl``, or where the file system refuses locks, no lock: the atomic rename alone still
    keeps the folder whole (two processes may then both build the stage; the first one wins).
    """
    try:
        import fcntl  # POSIX only: where it is missing, stages go unlocked (below)
    except ImportError:  # not POSIX
        yield
        return
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                log.info("waiting for another process building %s", path.name[1:-5])
                fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError as err:  # e.g. ENOLCK on a network file system without locks
            os.close(fd)
            log.warning("no lock on %s (%s): building without one", path, err)
            yield
            return
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder before removed this file: lock the one there now
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)
        os.close(fd)  # releases the lock


def _build(root: Path, key: str, final: Path, inputs: dict,
           build: Callable[[Path], dict]) -> tuple[Path, dict, bool]:
    """Build a stage into a work folder and rename it to ``final`` (see :func:`cached_stage`)."""
    meta_path = final / STAGE_FILE
    for old in root.glob(f".{key}.*.tmp"):  # left by a killed run before work folders
        shutil.rmtree(old, ignore_errors=True)  # carried their process id
    # removes the work folders of killed runs, keeps those of a concurrent run building this
    # same stage into the same folder now
    tmp = make_work_dir(final)
    try:
        t0 = time.perf_counter()
        meta = dict(build(tmp) or {})
        meta.update(key=key, inputs=inputs, build_s=time.perf_counter() - t0)
        write_json_atomic(tmp / STAGE_FILE, meta)
        if meta_path.is_file():  # a concurrent run finished the same stage first (no lock was
            shutil.rmtree(tmp, ignore_errors=True)  # to be had): keep its folder, the same
            return final, json.loads(meta_path.read_text()), True  # inputs give the same result
        if final.exists():  # an incomplete folder (no stage.json) from an older layout: moved
            aside = make_work_dir(final)  # aside in one rename, then removed
            os.replace(final, aside / "old")
            shutil.rmtree(aside, ignore_errors=True)
        try:
            os.replace(tmp, final)
        except OSError:  # the folder appeared meanwhile (a concurrent run without a lock)
            if not meta_path.is_file():
                raise
            shutil.rmtree(tmp, ignore_errors=True)
            return final, json.loads(meta_path.read_text()), True
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final, meta, False
