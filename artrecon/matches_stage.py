"""The matches stage: the two configurations in, everything the model takes from matching out.

Input: what :mod:`artrecon.configuration` left for each configuration (its SfM model with the
COLMAP database's descriptors, the object region and the background sample). Output: a folder
(``OUT/matches``), a contract like a configuration's::

    object.npz        the object's 3D-3D matches: points_a, points_b (SfM frames),
                      point3D_ids_a, point3D_ids_b, votes, colours (of the A point)
    background.npz    the background matches, the same arrays
    candidates.npz    the guided matching's candidates (the object's SfM points the matching left
                      out): ids_a, xyz_a, desc_a, ids_b, xyz_b, desc_b
                      (artrecon.features.PointDescriptors)
    covariances.npz   the triangulation covariances of all of these points, row for row
                      (artrecon.uncertainty.MatchCovariances); only when
                      ``segmentation.covariances`` is on
    matches.json      the record, written last: the inputs digests of both configurations, the
                      settings the matching reads (:func:`match_settings`), seed, artrecon
                      version, each file's SHA-256, counts and the timing

:func:`match_stage` writes it, :func:`check_matches` refuses one that is not this run's (the
record names other configurations, settings, seed or version; a file is missing or not the one
the record names), :func:`load_matches` reads it back. The links stage
(:mod:`artrecon.links_stage`) and the refinement always start from the folder, in a whole run
too, so a run continued from it (``--from links``) gives the whole run's model bit for bit. The
files are hashed once per run: as they are written, or, in a folder of an earlier run, when
:func:`check_matches` checks them.

Not to be confused with ``OUT/matches.npz`` (and ``OUT/links/matches.npz``, which it copies),
which the links stage writes: the matches the links were fitted to (the guided ones appended)
with their link labels.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from artrecon._version import __version__
from artrecon.errors import ReconstructionError
from artrecon.features import (
    CrossMatches,
    PointDescriptors,
    match_configurations,
    point_descriptors,
    tracked_features,
)
from artrecon.stage_record import (
    check_record,
    file_problems,
    inputs_digest,
    npz_bytes,
    read_record,
    stage_settings,
    write_stage,
)
from artrecon.uncertainty import MatchCovariances, point_covariances

log = logging.getLogger(__name__)

#: Version of the folder contract (``matches.json`` ``format``).
FORMAT = "artrecon-matches/1"
#: The record, written last: a folder without it holds no finished stage.
RECORD = "matches.json"
_MATCH_FIELDS = ("points_a", "points_b", "point3D_ids_a", "point3D_ids_b", "votes", "colours")
_COVARIANCE_FIELDS = ("matches_a", "matches_b", "background_a", "background_b", "candidates_a",
                      "candidates_b")


@dataclass
class Matching:
    """What the matches stage found (:func:`load_matches`).

    Attributes
    ----------
    matches : CrossMatches
        The object's 3D-3D matches.
    background : CrossMatches
        The background's.
    candidates : (PointDescriptors, PointDescriptors)
        The object's points of A and B the matching left out, for the guided matching.
    covariances : MatchCovariances or None
        Their triangulation covariances (None: ``segmentation.covariances`` off).
    record : dict
        ``matches.json``.
    """

    matches: CrossMatches
    background: CrossMatches
    candidates: tuple[PointDescriptors, PointDescriptors]
    covariances: MatchCovariances | None
    record: dict = field(default_factory=dict)


def match_settings(config) -> dict:
    """The settings the matches stage reads, as its record holds them (JSON: tuples are
    lists): all of ``config.match``, and ``segmentation.covariances`` (whether the covariances
    are computed). The other settings of the later stages (segmentation, guided matching,
    joints ...) do not change the folder."""
    return {**stage_settings(config, ("match",)),
            "segmentation": {"covariances": bool(config.segmentation.covariances)}}


def matches_digest(configurations: dict, settings: dict, seed: int) -> str:
    """SHA-256 of everything the stage's result depends on: the configurations (their records'
    ``inputs_digest``, ``{"a": ..., "b": ...}``), the settings (:func:`match_settings`), the
    seed and artrecon's version."""
    return inputs_digest({"configurations": configurations}, settings, seed)


def _required(covariances: bool) -> set[str]:
    """The files a record must name."""
    return {"object.npz", "background.npz", "candidates.npz"} | (
        {"covariances.npz"} if covariances else set())


def match_stage(confs: dict, folder: str | Path, config, seed: int) -> Matching:
    """Match the configurations ``confs`` (``{"a": Configuration, "b": ...}``,
    :class:`artrecon.configuration.Configuration`) and write the stage's folder (see the module
    docstring; the record last). Run it with one BLAS and OpenCV thread (the whole run's
    results are those). Returns what it wrote, as :func:`load_matches` reads it.

    Raises
    ------
    ReconstructionError
        Too few matches (:func:`artrecon.features.match_configurations`).
    """
    folder = Path(folder)
    t = time.perf_counter()
    sfms = {k: c.sfm for k, c in confs.items()}
    regions = {k: c.object_ids for k, c in confs.items()}
    backgrounds = {k: c.background_ids for k, c in confs.items()}
    feats = {k: tracked_features(sfms[k], regions[k] | backgrounds[k]) for k in ("a", "b")}
    matches = match_configurations(sfms["a"], sfms["b"], config.match, seed,
                                   features=(feats["a"], feats["b"]))
    in_a = np.isin(matches.point3D_ids_a, list(regions["a"]))
    in_b = np.isin(matches.point3D_ids_b, list(regions["b"]))
    background = matches.subset(~in_a & ~in_b)
    matches = matches.subset(in_a & in_b)
    # the object's points the matching left out, for the guided matching
    candidates = []
    for key, matched in (("a", matches.point3D_ids_a), ("b", matches.point3D_ids_b)):
        desc = point_descriptors(sfms[key], feats[key])
        keep = np.isin(desc.ids, list(regions[key])) & ~np.isin(desc.ids, matched)
        candidates.append(PointDescriptors(desc.ids[keep], desc.xyz[keep], desc.desc[keep]))
    # how precisely each point is known (its track's views), for the links' motions
    covariances = None
    if config.segmentation.covariances:
        cov = {}
        for key in ("a", "b"):
            rec = sfms[key].reconstruction
            ids_m = matches.point3D_ids_a if key == "a" else matches.point3D_ids_b
            ids_g = background.point3D_ids_a if key == "a" else background.point3D_ids_b
            ids_c = candidates[0 if key == "a" else 1].ids
            cov[key] = [point_covariances(rec, ids) for ids in (ids_m, ids_g, ids_c)]
        covariances = MatchCovariances(cov["a"][0], cov["b"][0], cov["a"][1], cov["b"][1],
                                       cov["a"][2], cov["b"][2])
    seconds = time.perf_counter() - t
    files = {
        "object.npz": {k: getattr(matches, k) for k in _MATCH_FIELDS},
        "background.npz": {k: getattr(background, k) for k in _MATCH_FIELDS},
        "candidates.npz": {f"{name}_{key}": getattr(c, name)
                           for key, c in zip(("a", "b"), candidates, strict=True)
                           for name in ("ids", "xyz", "desc")},
    }
    if covariances is not None:
        files["covariances.npz"] = {k: getattr(covariances, k) for k in _COVARIANCE_FIELDS}
    settings = match_settings(config)
    configurations = {k: confs[k].record["inputs_digest"] for k in ("a", "b")}
    record = write_stage(folder, {name: npz_bytes(arrays) for name, arrays in files.items()}, {
        "format": FORMAT, "inputs_digest": matches_digest(configurations, settings, seed),
        "configurations": configurations, "settings": settings, "seed": seed,
        "artrecon_version": __version__,
        "matches": len(matches), "background_matches": len(background),
        "candidates": {"a": len(candidates[0]), "b": len(candidates[1])},
        "covariances": covariances is not None, "timings": {"match": seconds},
    }, RECORD)
    log.info("matches: %d on the object, %d on the background, %d + %d candidates (%.1f s)",
             len(matches), len(background), len(candidates[0]), len(candidates[1]), seconds)
    # read back as a later run reads it (the files just hashed as they were written)
    return _read_matches(folder, record)


def check_matches(folder: str | Path, configurations: dict, config, seed: int, *,
                  restart: str = "run from the start") -> dict:
    """Refuse a folder that is not a finished matches stage of exactly these configurations,
    settings and seed (a run told to start after the stage, ``--from links``, asks here first;
    nothing is ever recomputed quietly).

    Parameters
    ----------
    folder : str or Path
    configurations : dict
        ``{"a": inputs_digest, "b": ...}`` of the configurations this run starts from (their
        records, already checked against this run's inputs).
    config : ReconstructConfig
        This run's settings; only :func:`match_settings` of them must agree.
    seed : int
    restart : str
        What the user should do instead, for messages.

    Returns
    -------
    dict
        The folder's record.

    Raises
    ------
    InputError
        No record (no matches stage, or an interrupted one), a record of another format, one
        made from other configurations, settings, seed or version (the message names what
        differs), or files missing or changed.
    """
    def upstream_differences(record: dict) -> list[str]:
        there = record.get("configurations") or {}
        return [f"configuration {k.upper()} is not the one they were matched in (its "
                "configuration.json was written since)"
                for k in sorted(configurations) if there.get(k) != configurations[k]]

    return check_record(Path(folder), RECORD, FORMAT, "matches",
                        {"configurations": configurations}, match_settings(config), seed,
                        required=_required(bool(config.segmentation.covariances)),
                        restart=restart, made_from="configurations",
                        upstream_differences=upstream_differences)


def load_matches(folder: str | Path, record: dict | None = None) -> Matching:
    """Read a folder written by :func:`match_stage` (its files checked against the record,
    unless ``record`` is given: the folder's record, already checked by :func:`check_matches`).

    Raises
    ------
    ReconstructionError
        The folder is incomplete (no record, a file missing or changed) or of another format.
    """
    folder = Path(folder)
    if record is not None:
        return _read_matches(folder, record)
    record = read_record(folder, RECORD, FORMAT, "matches", "reconstruct again",
                         error=ReconstructionError)
    problems = file_problems(folder, record, _required(bool(record.get("covariances"))))
    if problems:
        raise ReconstructionError(f"the matches in {folder} are incomplete: "
                                  f"{'; '.join(problems)}; reconstruct again")
    return _read_matches(folder, record)


def _read_matches(folder: Path, record: dict) -> Matching:
    """The folder's arrays, its record ``record`` (checked, or just written)."""

    def arrays(name: str) -> dict:
        with np.load(folder / name) as npz:
            return {k: npz[k] for k in npz.files}

    obj, bg, cand = arrays("object.npz"), arrays("background.npz"), arrays("candidates.npz")
    candidates = tuple(PointDescriptors(cand[f"ids_{k}"], cand[f"xyz_{k}"], cand[f"desc_{k}"])
                       for k in ("a", "b"))
    covariances = None
    if record.get("covariances"):
        cov = arrays("covariances.npz")
        covariances = MatchCovariances(**{k: cov[k] for k in _COVARIANCE_FIELDS})
    return Matching(CrossMatches(**{k: obj[k] for k in _MATCH_FIELDS}),
                    CrossMatches(**{k: bg[k] for k in _MATCH_FIELDS}), candidates, covariances,
                    record)
