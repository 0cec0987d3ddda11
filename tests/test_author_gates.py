"""Imported objects pass the main job's gates (issue 24): a PartNet-Mobility-style URDF (a box
chest, a revolute lid, a prismatic drawer, OBJ meshes without UVs) and an MJCF cabinet (STL
meshes in millimetres scaled by the file, euler orientations in degrees, a hinged door) are
imported with ``python -m sim.author import`` at its defaults into a folder outside ``scenes/``,
and each is evaluated exactly as ``python -m sim.evaluate PATH`` evaluates it by default
(:class:`sim.evaluate.EvalConfig` at its defaults: 36 views per ring, FK poses, seed 0,
manipulation on), then judged gate by gate by :mod:`sim.evaluate.gates` (never loosened here).

Slow (one full evaluation per object, minutes each). ``ARTRECON_AUTHOR_OUT=DIR`` keeps the
imported scenes and the evaluation folder (results.json there holds the figures).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from author_objects import write_mjcf_cabinet, write_partnet_chest
from test_gates import assert_gate, gate_params, write_report

import sim  # noqa: F401
from sim import evaluate
from sim.author import ImportConfig, import_object

pytestmark = pytest.mark.slow

OBJECTS = {"chest": (write_partnet_chest, "partnet_chest"),
           "mm_cabinet": (write_mjcf_cabinet, "mjcf_cabinet")}
_RESULTS: dict[str, dict] = {}

#: {(object, gate): reason} of the gates an imported object misses at the default configuration,
#: with the figure measured; strict xfails, as in test_gates: the day one passes, its entry must
#: go.
KNOWN_MISSES: dict[tuple[str, str], str] = {}
# chest's segmentation (0.942 at 54277f2: B's points 0.921, its drawer's floor pulled to the
# carcass by the table in the dense labelling's second pass) passes since the labelling's
# silent-fit tie takes hidden counterparts into account: 0.973 (A 0.958, B 0.992)

#: Plain xfails (see test_gates.MACHINE_DEPENDENT): none. mm_cabinet's manipulation was one (the
#: gripper stopped 6.0 mm from its grasp with one branch; 2.18 N against the 2 N floor at
#: 30faea6); it passed (XPASS) in CI on this machine at 54277f2, 1943f29 and cce5deb (2.5 N at
#: 59aa268), so it is gated like any other.
MACHINE_DEPENDENT: dict[tuple[str, str], str] = {}

#: Objects whose listed misses were not measured at the current code (plain xfails).
NOT_REMEASURED: frozenset[str] = frozenset()


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory) -> Path:
    keep = os.environ.get("ARTRECON_AUTHOR_OUT")
    return Path(keep) if keep else tmp_path_factory.mktemp("author_gates")


@pytest.fixture(scope="module", autouse=True)
def _write_report(out_dir):
    yield
    if _RESULTS:
        write_report(_RESULTS, out_dir / "eval", "pytest tests/test_author_gates.py")


def _result(name: str, out_dir: Path) -> dict:
    if name not in _RESULTS:
        write, folder = OBJECTS[name]
        source = write(out_dir / "sources" / folder)
        scene = out_dir / "scenes" / f"{name}.xml"
        if not scene.is_file():
            import_object(source, scene.parent, ImportConfig(name=name))
        _RESULTS[name] = evaluate.evaluate_scene(str(scene), evaluate.EvalConfig(progress=False),
                                                 out_dir / "eval")
    return _RESULTS[name]


@pytest.mark.parametrize(("name", "gate"), gate_params(OBJECTS, KNOWN_MISSES, NOT_REMEASURED,
                                                      MACHINE_DEPENDENT))
def test_imported_object_meets_the_gate(name, gate, out_dir):
    assert_gate(name, _result(name, out_dir), gate)
