"""The record of a stage folder after matching (``OUT/matches``, ``OUT/links``, ``OUT/joints``,
``OUT/refine``): one copy of how such a folder is written, checked and trusted.

Every one of these folders ends in a JSON record written last (a folder without it holds no
finished stage) naming its format, what the stage was made from (the record digest of the stage
or stages before it), the settings it reads, the seed, artrecon's version and each of its files'
SHA-256; its ``inputs_digest`` hashes all of that but the files. A run that starts after the
stage checks the record against its own inputs and settings (:func:`check_record`) and the files
against the record, once; a run that writes the folder reads it back without hashing it again
(it has just hashed the bytes it wrote).
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from artrecon._version import __version__
from artrecon.errors import InputError, ReconstructionError
from artrecon.files import read_json, write_bytes_atomic, write_json_atomic


def stage_settings(config, stages: tuple[str, ...]) -> dict:
    """``{stage: asdict(config.<stage>)}`` for the named stages of a ReconstructConfig, as JSON
    values (tuples are lists), as a record holds them."""
    return json.loads(json.dumps({s: asdict(getattr(config, s)) for s in stages}, default=str))


def inputs_digest(upstream: dict, settings: dict, seed: int) -> str:
    """SHA-256 of everything a stage's result depends on: ``upstream`` (``{"matches": digest}``
    and the like: the records of the stages it reads), its settings, the seed and artrecon's
    version."""
    return hashlib.sha256(json.dumps({**upstream, "settings": settings, "seed": seed,
                                      "version": __version__},
                                     sort_keys=True).encode()).hexdigest()


def npz_bytes(arrays: dict) -> bytes:
    """The bytes of ``np.savez(arrays)`` (to hash what is written)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def write_stage(folder: Path, files: dict[str, bytes], record: dict, record_name: str) -> dict:
    """Write ``files`` (name -> bytes) into ``folder``, then the record (``record`` with the
    files' SHA-256 under ``"files"``) last. Returns the record."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    digests = {}
    for name, data in files.items():
        write_bytes_atomic(folder / name, data)
        digests[name] = hashlib.sha256(data).hexdigest()
    record = {**record, "files": digests}
    write_json_atomic(folder / record_name, record)  # last: a folder without it is incomplete
    return record


def file_problems(folder: Path, record: dict, required: set[str]) -> list[str]:
    """The files the record names that are missing or hold other bytes than it names
    (``required``: names the record must list)."""
    files = record.get("files")
    if not isinstance(files, dict) or not required <= set(files):
        return ["the record does not name the stage's files"]
    out = []
    for name, digest in sorted(files.items()):
        path = Path(folder) / name
        if not path.is_file():
            out.append(f"{name} is missing")
        elif hashlib.sha256(path.read_bytes()).hexdigest() != digest:
            out.append(f"{name} is not the file the record names (changed or half-written)")
    return out


def read_record(folder: Path, record_name: str, fmt: str, what: str, restart: str,
                error=InputError) -> dict:
    """The record of a finished stage in ``folder`` (``error`` when there is none, or of
    another format; ``what``: the stage's name, plural, for messages, e.g. ``"links"``)."""
    path = Path(folder) / record_name
    if not path.is_file():
        raise error(f"{folder} holds no finished {what} stage (no {record_name}; a run stopped "
                    f"before it, or interrupted); {restart}")
    record = read_json(path)
    if not isinstance(record, dict) or record.get("format") != fmt:
        got = record.get("format") if isinstance(record, dict) else None
        raise error(f"{path}: format {got!r}, this artrecon reads {fmt!r}; {restart}")
    return record


def record_of(folder: Path, record: dict | None, record_name: str, fmt: str, what: str) -> dict:
    """``record`` when given (the folder's record, already checked), else the folder's record
    read with its files trusted (ReconstructionError when there is none, or of another format):
    how a stage's ``load_*`` finds the record of a folder this run wrote or checked."""
    if record is not None:
        return record
    return read_record(folder, record_name, fmt, what, "reconstruct again",
                       error=ReconstructionError)


def check_record(folder: Path, record_name: str, fmt: str, what: str, upstream: dict,
                 settings: dict, seed: int, *, required: set[str], restart: str,
                 made_from: str = "inputs", upstream_differences=None) -> dict:
    """Refuse a folder that is not a finished stage of exactly this run (its record made from
    another ``upstream``, ``settings``, seed or version; a file missing or changed): InputError
    naming what differs and ``restart``. Returns the record.

    ``upstream_differences(record)`` lists how the record's upstream differs, in words (default:
    the upstream stage's record was written since).
    """
    record = read_record(folder, record_name, fmt, what, restart)
    if record.get("inputs_digest") != inputs_digest(upstream, settings, seed):
        if upstream_differences is None:
            ups = [f"OUT/{k}/ is not the one it was made from (its record was written since)"
                   for k in sorted(upstream) if record.get(k) != upstream[k]]
        else:
            ups = upstream_differences(record)
        differs = "; ".join(differences(record, settings, seed, ups))
        raise InputError(f"the {what} in {folder} were made from other {made_from} or "
                         f"settings than this run's ({differs}), so they are not reused; "
                         f"{restart}, or give the settings they were made with")
    problems = file_problems(folder, record, required)
    if problems:
        raise InputError(f"the {what} in {folder} are incomplete: {'; '.join(problems)}; "
                         f"{restart}")
    return record


def differences(record: dict, settings: dict, seed: int, upstream: list[str]) -> list[str]:
    """What a record names otherwise than this run: version, seed, ``upstream`` (already in
    words), each setting."""
    out = []
    if record.get("artrecon_version") != __version__:
        out.append(f"artrecon {record.get('artrecon_version')} made them, this is "
                   f"{__version__}")
    if record.get("seed") != seed:
        out.append(f"seed {record.get('seed')} there, {seed} now")
    out += upstream
    recorded = record.get("settings") or {}
    for stage in sorted(set(settings) | set(recorded)):
        a, b = recorded.get(stage) or {}, settings.get(stage) or {}
        out += [f"{stage}.{k}: {a.get(k)!r} there, {b.get(k)!r} now"
                for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
    return out or ["the record's digest"]
