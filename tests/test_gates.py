"""The accuracy gates of the main job (issue 19): every bundled scene, evaluated exactly as
``python -m sim.evaluate`` evaluates it by default, judged by the same verdict.

One evaluation per scene (module fixture, :class:`sim.evaluate.EvalConfig` at its defaults:
36 views per ring, the arm's FK camera poses, seed 0, manipulation on), then each gate of
:data:`sim.evaluate.gates.GATE_NAMES` is its own test per scene, so a report shows which figure
failed and by how much. The limits live in :data:`sim.evaluate.gates.GATES` and are never
loosened here. ``ARTRECON_GATES_OUT=DIR`` keeps the evaluation folder (its stage cache serves the
next session; results.json and results.md there hold the figures behind the gates).

A scene that misses a gate stays visible: it is listed in :data:`KNOWN_MISSES` with its figure
and reason, as a strict xfail (the day it passes, the entry must go), and the main job marks it
FAIL and exits non-zero.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
import pytest

import sim  # noqa: F401
from sim import evaluate
from sim.evaluate import gates, record, report
from sim.scene import list_scenes, load_scene

pytestmark = pytest.mark.slow

#: Every bundled scene: none is skipped or run at easier settings.
SCENES = tuple(list_scenes())

#: {(scene, gate): reason} of the gates a scene misses at the default configuration, with the
#: figure measured by the main job on the 2-core machine; strict xfails (the day one passes, its
#: entry must go), except for the scenes of NOT_REMEASURED. Empty: with the survey's view plan
#: (2026-11-27, the main job on all ten scenes, AVX-512 machine) every scene passes every gate:
#: segmentation 0.975-0.994 (pliers 0.975, pliers_panda 0.976, scissors 0.977), the largest axis
#: error 0.39 deg (scissors), cabinet's door and drawer moved with the grasp ranking that prefers
#: a pull along the gripper (the door's handle from the front).
KNOWN_MISSES: dict[tuple[str, str], str] = {}

#: Scenes whose listed misses were not measured again after the last change that can alter
#: them: their entries are plain xfails, so a pass shows as XPASS instead of failing the suite,
#: while a gate not listed still fails it. Empty when every scene was measured at the current
#: code.
NOT_REMEASURED: frozenset[str] = frozenset()

#: {(scene, gate): reason} of the gates a scene passes on one machine and misses on another,
#: with the figures of each: plain xfails (a pass is reported as XPASS, a miss as XFAIL; the
#: main job says FAIL wherever it misses). The same code, seed and package versions give
#: different figures on CPUs with different vector units: numpy's and OpenBLAS's kernels and
#: OpenCV's dispatch use AVX-512 on one machine of this kind and not on another (the renders did
#: not change with llvmpipe's vector width; forcing the AVX2 paths on the AVX-512 machine moved
#: scraper_truck's axes from 0.74 / 0.80 to 0.64 / 0.69 deg at 911bcef), and where a figure sits
#: near its limit the verdict follows the CPU. Measured: CI's run of b54bd20 (2026-11-25) and
#: the main job on the AVX-512 machine at 911bcef, 847ccaa and 09052e6 (2026-11-26). Empty since
#: drawer's segmentation, its one entry (0.954 here, >= 0.97 on CI at b54bd20), measures 0.995.
MACHINE_DEPENDENT: dict[tuple[str, str], str] = {}

_RESULTS: dict[str, dict] = {}


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory) -> Path:
    keep = os.environ.get("ARTRECON_GATES_OUT")
    return Path(keep) / "gates" if keep else tmp_path_factory.mktemp("gates")


def write_report(results: dict[str, dict], out_dir: Path, command: str) -> None:
    """results.json / results.md of the evaluations in ``results``, as the main job writes
    them, merged with the scenes the folder already reports: the scenes of one module run in
    both xdist workers (tests/conftest.py), each writing the ones it ran (under a lock). A
    results.json of another schema (a folder kept from older code) is replaced, with a
    warning, not merged."""
    import fcntl

    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".results.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        scenes = {}
        if (out_dir / "results.json").is_file():
            try:
                old = record.read_results(out_dir / "results.json")
                scenes = {n: r.to_json() for n, r in (old.scenes or {}).items()}
            except record.SchemaError as err:
                warnings.warn(f"not merged: {err}", stacklevel=1)
        scenes.update({n: report.jsonable_scene(r) for n, r in results.items()})
        meta = evaluate.run_meta(evaluate.EvalConfig(progress=False), command)
        meta["scene_hashes"] = {n: r.get("scene_hash") for n, r in scenes.items()}
        report.write_results({"scenes": dict(sorted(scenes.items())), "meta": meta}, out_dir)


@pytest.fixture(scope="module", autouse=True)
def _write_report(out_dir):
    """After the module: results.json / results.md of what ran, as the main job writes them."""
    yield
    if _RESULTS:
        write_report(_RESULTS, out_dir, "pytest tests/test_gates.py")


def _result(name: str, out_dir: Path) -> dict:
    """The scene's evaluation at the main job's defaults, run once per session."""
    if name not in _RESULTS:
        _RESULTS[name] = evaluate.evaluate_scene(name, evaluate.EvalConfig(progress=False),
                                                 out_dir)
    return _RESULTS[name]


def test_the_gates_run_the_main_jobs_defaults():
    """The configuration gated here is the command line's default, field by field (progress
    bars aside)."""
    from dataclasses import replace

    from sim.evaluate import cli

    cli_default = cli.config_from_args(cli.parser().parse_args([]))
    assert replace(cli_default, progress=False) == evaluate.EvalConfig(progress=False)


def gate_params(names, known_misses: dict[tuple[str, str], str],
                not_remeasured: frozenset[str] = frozenset(),
                machine_dependent: dict[tuple[str, str], str] | None = None) -> list:
    """(name, gate) for every gate of every name; a known miss as a strict xfail with its
    reason (also used by test_author_gates); for a scene in ``not_remeasured`` a plain xfail
    (its last figure predates a change that may have fixed it: a pass is reported, not failed);
    a gate of ``machine_dependent`` (missed on one machine, passed on another) a plain xfail
    with the figures of both."""
    machine_dependent = machine_dependent or {}
    out = []
    for n in names:
        for g in gates.GATE_NAMES:
            if (n, g) in known_misses:
                mark = pytest.mark.xfail(strict=n not in not_remeasured,
                                         reason=known_misses[(n, g)])
            elif (n, g) in machine_dependent:
                mark = pytest.mark.xfail(strict=False, reason=machine_dependent[(n, g)])
            else:
                out.append(pytest.param(n, g))
                continue
            out.append(pytest.param(n, g, marks=mark))
    return out


def assert_gate(name: str, result: dict, gate: str) -> None:
    """One gate family of one evaluation, as the main job's verdict judges it."""
    checks = [c for c in gates.checks(result) if gates.family(c.gate) == gate]
    failed = [c.describe() for c in checks if not c.passed]
    assert not failed, f"{name}: " + "; ".join(failed)
    if gate == "error":
        assert result["error"] is None


@pytest.mark.parametrize(("name", "gate"), gate_params(SCENES, KNOWN_MISSES, NOT_REMEASURED,
                                                      MACHINE_DEPENDENT))
def test_gate(name, gate, out_dir):
    """One gate of one scene, as the main job's verdict judges it."""
    assert_gate(name, _result(name, out_dir), gate)


@pytest.mark.parametrize("name", SCENES)
def test_verdict_is_the_gates(name, out_dir):
    """The scene's recorded verdict is the gates' (one definition)."""
    r = _result(name, out_dir)
    v = gates.verdict(r)
    assert (r["passed"], r["failed_gates"]) == (v["passed"], v["failed"])


@pytest.mark.parametrize("name", SCENES)
def test_every_planned_view_captured(name, out_dir):
    r = _result(name, out_dir)
    if r["error"]:
        pytest.skip(f"{name} failed: {r['error']} (test_gate[{name}-error] reports it)")
    for cfg in ("capture_a", "capture_b"):
        cap = r[cfg]
        assert cap["n_planned"] > 0 and cap["n_captured"] == cap["n_planned"], (name, cfg, cap)
        # the recorded poses are the arm's forward kinematics, and they are where the camera was
        assert cap["max_fk_position_error_mm"] < 1e-6, (name, cfg, cap)


#: The dense points against the true surfaces (issue 5): median within 3 mm.
DENSE_ACCURACY_MEDIAN_MM = 3.0


@pytest.mark.parametrize("name", SCENES)
def test_dense_points_lie_on_the_true_surfaces(name, out_dir):
    r = _result(name, out_dir)
    if r["error"]:
        pytest.skip(f"{name} failed: {r['error']} (test_gate[{name}-error] reports it)")
    assert r["model"]["accuracy_median_mm"] <= DENSE_ACCURACY_MEDIAN_MM, (name, r["model"])


#: Issue 8 on the reconstruction: the twin, driven by the true motion, must put its points within
#: "a few mm" of the true surface; the median over each link's points.
TWIN_MEDIAN_MM = 5.0


@pytest.mark.parametrize("name", [s for s in SCENES if len(load_scene(s).moving_joints) == 1])
def test_exported_twin_moves_like_the_true_object(name, out_dir, tmp_path):
    """The registered reconstruction exported as MJCF and URDF, its joint driven by the true
    object's motion in MuJoCo and pinocchio: the twin's points land on the true surfaces of
    configuration B."""
    from scipy.spatial import cKDTree
    from test_export import mujoco_points, pinocchio_points

    from artrecon import export as ex

    r = _result(name, out_dir)
    if r["error"]:
        pytest.skip(f"{name} failed: {r['error']} (test_gate[{name}-error] reports it)")
    model = r["_registered"]
    scene = load_scene(name)
    (row,) = r["joints"]
    (true_joint,) = scene.moving_joints
    assert not row["links_swapped"], f"{name}: the twin's base is the true moving link"
    idx = next(k for k, j in enumerate(model.joints) if j.name == row["estimated_joint"])
    twin = ex.build_twin(model)
    tj = twin.joints[idx]
    assert np.sign(tj.motion) == np.sign(model.joints[idx].motion)
    value = {tj.name: float(np.sign(tj.motion) * abs(true_joint.motion))}
    xml = ex.export_mjcf(twin, tmp_path / f"{name}.xml")[-1]
    urdf = ex.export_urdf(twin, tmp_path / f"{name}.urdf")[-1]
    pts_mj, _ = mujoco_points(xml, twin, value)
    pts_pin, _ = pinocchio_points(urdf, twin, value)
    samples, _ = evaluate.sample_surface(scene, "b", seed=0)
    tree = cKDTree(samples)
    medians = {}
    for lk, p_mj, p_pin in zip(twin.links, pts_mj, pts_pin, strict=True):
        np.testing.assert_allclose(p_mj, p_pin, atol=1e-9)
        medians[lk.name] = round(float(np.median(tree.query(p_mj)[0] * 1e3)), 2)
    assert all(m <= TWIN_MEDIAN_MM for m in medians.values()), (name, medians)
