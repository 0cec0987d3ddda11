"""The joints stage: the links in, the kinematic tree and the joints out.

Input: ``OUT/links/`` (:mod:`artrecon.links_stage`, read back with the configurations' dense
points). The steps are :func:`artrecon.articulation.find_joints`'s: the kinematic tree of
adjacent links (rooted at the base), each joint's type, axis and state, and its evidence (a
joint too weakly supported is refused, WeakEvidenceError). Output: a folder (``OUT/joints``)::

    tree.json       the kinematic tree as model.json's metadata holds it (:func:`tree_record`:
                    edges, root, margin, every adjacent pair's figures) and each link's parent
    estimates.json  the joints in model.json's encoding (:func:`artrecon.model.joint_to_dict`,
                    each with its evidence in ``confidence``) and the evidence's summary
                    (``confidence``: gates, bootstrap samples, per joint score and verdict)
    joints.json     the record, written last: the links' inputs_digest, the settings the stage
                    reads (``joints.*``, ``confidence.*``), seed, artrecon version, each file's
                    SHA-256, counts and the timing

:func:`run_joints` writes it and reads it back, :func:`check_joints` refuses one that is not
this run's, :func:`load_joints` reads it. The tree read back holds what the later stages use
(root, parents, edges, the pairs' figures, margin), not the gap and cost matrices.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from artrecon._version import __version__
from artrecon.articulation import JointSet, Links, find_joints
from artrecon.diagnosis import blame_poses
from artrecon.errors import DegenerateError, WeakEvidenceError
from artrecon.files import read_json
from artrecon.joints import KinematicTree
from artrecon.model import joint_from_dict, joint_to_dict
from artrecon.stage_record import (
    check_record,
    inputs_digest,
    record_of,
    stage_settings,
    write_stage,
)

log = logging.getLogger(__name__)

#: Version of the folder contract (``joints.json`` ``format``).
FORMAT = "artrecon-joints/1"
#: The record, written last.
RECORD = "joints.json"
#: The settings the stage reads (``--from refine`` needs them unchanged).
SETTINGS = ("joints", "confidence")
_REQUIRED = {"tree.json", "estimates.json"}


def run_joints(confs: dict, links: Links, folder: Path, config, seed: int,
               links_digest: str) -> JointSet:
    """The joints of ``links`` (:class:`artrecon.articulation.Links`, the links stage's folder
    read back; its record's ``inputs_digest`` is ``links_digest``), written to ``folder`` and
    read back as :func:`load_joints` reads it. ``confs``: the configurations (their given
    poses' agreement with the images names a likely cause of a failure).

    Raises
    ------
    WeakEvidenceError
        A joint's evidence is too weak for its axis (artrecon.confidence).
    """
    try:
        found = find_joints(links, config, seed)
    except (DegenerateError, WeakEvidenceError) as exc:
        raise blame_poses(exc, {k: c.sfm for k, c in confs.items()}, config.sfm) from exc
    tree = {**tree_record(found.tree), "parents": [int(p) for p in found.tree.parents]}
    estimates = {"joints": [joint_to_dict(j) for j in found.joints],
                 "confidence": found.confidence}
    settings = stage_settings(config, SETTINGS)
    upstream = {"links": links_digest}
    record = write_stage(folder, {"tree.json": _json_bytes(tree),
                                  "estimates.json": _json_bytes(estimates)}, {
        "format": FORMAT, "inputs_digest": inputs_digest(upstream, settings, seed), **upstream,
        "settings": settings, "seed": seed, "artrecon_version": __version__,
        "joints": len(found.joints), "timings": found.timings,
    }, RECORD)
    return _read_joints(Path(folder), record)


def _json_bytes(obj) -> bytes:
    # as model.json writes its figures (NaN and infinity kept: a joint's evidence may hold them)
    return json.dumps(obj, indent=1).encode()


def check_joints(folder: Path, links_digest: str, config, seed: int, *, restart: str) -> dict:
    """Refuse a folder that is not a finished joints stage of these links (their record's
    ``inputs_digest``), settings (``joints.*``, ``confidence.*``) and seed: InputError naming
    what differs and ``restart``. Returns the record."""
    return check_record(Path(folder), RECORD, FORMAT, "joints", {"links": links_digest},
                        stage_settings(config, SETTINGS), seed, required=_REQUIRED,
                        restart=restart)


def load_joints(folder: Path, record: dict | None = None) -> JointSet:
    """The tree and joints of a folder written by :func:`run_joints` (``record``: its record,
    already checked by :func:`check_joints`; without it, read, the files trusted).
    (ReconstructionError: no record, or one of another format.)
    """
    folder = Path(folder)
    return _read_joints(folder, record_of(folder, record, RECORD, FORMAT, "joints"))


def _read_joints(folder: Path, record: dict) -> JointSet:
    tree = read_json(folder / "tree.json")
    estimates = read_json(folder / "estimates.json")
    margin = tree["margin"]
    kinematic = KinematicTree(
        root=int(tree["root"]), parents=np.array(tree["parents"], int),
        edges=[tuple(e) for e in tree["edges"]],
        edge_figures={tuple(p["links"]): {k: v for k, v in p.items() if k != "links"}
                      for p in tree["pairs"]},
        margin=float("inf") if margin is None else float(margin))
    return JointSet(kinematic, [joint_from_dict(j) for j in estimates["joints"]],
                    estimates["confidence"], dict(record["timings"]))


def tree_record(tree: KinematicTree) -> dict:
    """The tree's choice, for model.json: its edges, its margin over the next best tree and every
    adjacent pair's figures (:attr:`KinematicTree.edge_figures`)."""
    return {"edges": [list(e) for e in tree.edges], "root": int(tree.root),
            "margin": float(tree.margin) if np.isfinite(tree.margin) else None,
            "pairs": [{"links": list(pair), **{k: (list(v) if isinstance(v, tuple) else v)
                                               for k, v in fig.items()}}
                      for pair, fig in sorted(tree.edge_figures.items())]}
