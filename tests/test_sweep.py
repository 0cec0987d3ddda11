"""Sweeps (issue 26): runs in parallel on worker processes and on Ray, merged; a worker that
dies is retried, then reported; resume; the stage cache shared by concurrent workers.

The machinery is tested with a light run function in place of
:func:`sim.evaluate.runner.evaluate_scene` (same signature, figures known from the seed, a few
milliseconds); one real sweep (slow) runs the harness itself on two worker processes.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from pathlib import Path

import pytest

import sim  # noqa: F401
from sim import cache
from sim.evaluate import cli, gates, pictures, record, sweep
from sim.evaluate.config import EvalConfig
from sim.perturb import Perturbation

# ---------------------------------------------------------------------------- light runs
# Importable by the worker processes (spawn gets this process's sys.path); Ray gets them by value.


def light_run(name: str, ev: EvalConfig, out_dir: Path) -> dict:
    """A scene result with the shape of evaluate_scene's: one revolute joint whose axis error is
    0.1 deg per (seed + 1), plus the image noise if any; seed 5 and up miss the 0.5 deg gate."""
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    (Path(out_dir) / f"ran-{ev.seed}.txt").write_text(str(os.getpid()))
    angle = 0.1 * (ev.seed + 1) + 0.01 * ev.perturb.image_noise_sigma
    res = {"scene": name, "error": None, "error_stage": None, "scene_hash": "h-" + name,
           "joints": [{"name": "hinge", "type_true": "revolute", "type_estimated": "revolute",
                       "type_correct": True, "estimated_joint": "e0", "links_swapped": False,
                       "axis_angle_deg": angle, "axis_position_mm": 0.2 * ev.seed,
                       "state_error": 0.05, "state_error_unit": "deg"}],
           "tree_correct": True, "invented_joints": [], "segmentation_accuracy": 0.99,
           "segmentation": {"off_surface_share": 0.01}, "manipulation": None,
           "registration": {"truth_errors": {"pnp": {"rotation_deg": 0.01, "translation_mm": 0.1,
                                                      "scale_percent": 0.01}}},
           "wall_s": 0.01}
    res["joints"][0]["passes"] = gates.joint_passes(res["joints"][0])
    v = gates.verdict(res, manipulate=ev.manipulate)
    res.update(passed=v["passed"], failed_gates=v["failed"])
    return res


def dying_run(name: str, ev: EvalConfig, out_dir: Path) -> dict:
    """:func:`light_run`, but the first attempt of seed 1 kills its worker process."""
    marker = Path(out_dir) / "died-once"
    if ev.seed == 1 and not marker.exists():
        marker.write_text("x")
        os._exit(3)
    return light_run(name, ev, out_dir)


def always_dying_run(name: str, ev: EvalConfig, out_dir: Path) -> dict:
    """Seed 1's worker dies on every attempt."""
    if ev.seed == 1:
        os._exit(4)
    return light_run(name, ev, out_dir)


def raising_run(name: str, ev: EvalConfig, out_dir: Path) -> dict:
    raise RuntimeError("not the harness")


def _specs(seeds=(0, 1, 2), scenes=("pliers", "truck")):
    ev = EvalConfig(views=12, manipulate=False, progress=False)
    return sweep.plan(scenes, ev, seeds)


def _stable(results: dict) -> list:
    """The merged runs without what depends on where and when they ran."""
    out = []
    for rec in results["runs"]:
        r = {k: v for k, v in rec.items() if k not in ("worker", "attempts")}
        r["result"] = {k: v for k, v in (rec["result"] or {}).items()
                       if k not in ("wall_s", "attempts")}
        out.append(r)
    return out


# ---------------------------------------------------------------------------- specs, seeds


@pytest.mark.parametrize("text, seeds", [("0-4", [0, 1, 2, 3, 4]), ("3", [3]),
                                         ("0,2,7", [0, 2, 7]), ("0-2,9,1", [0, 1, 2, 9])])
def test_parse_seeds(text, seeds):
    assert sweep.parse_seeds(text) == seeds


@pytest.mark.parametrize("text", ["4-2", "a", "1-", "-1", ""])
def test_parse_seeds_refuses_nonsense(text):
    with pytest.raises(ValueError, match="seeds"):
        sweep.parse_seeds(text)


def test_run_ids_name_scene_seed_and_label():
    spec = sweep.RunSpec("scenes/pliers.xml", EvalConfig(seed=3), label="noise 4")
    assert spec.run_id == "pliers-seed3-noise_4" and spec.group == "pliers-noise_4"
    with pytest.raises(sweep.SweepError, match="twice"):
        sweep.run_sweep([spec, spec], "/nonexistent/never-written", run_fn=light_run)


# ---------------------------------------------------------------------------- the sweep


def test_sweep_merges_every_run_with_median_worst_and_spread(tmp_path):
    res = sweep.run_sweep(_specs(seeds=range(6), scenes=("pliers",)), tmp_path,
                          sweep.SweepConfig(progress=False), run_fn=light_run)
    assert [r["id"] for r in res["runs"]] == [f"pliers-seed{s}" for s in range(6)]
    assert [r["status"] for r in res["runs"]] == ["passed"] * 5 + ["failed"]
    (group,) = res["summary"]
    axis = group["figures"]["hinge axis angle"]
    assert group["passed"] == 5 and group["failed"] == ["pliers-seed5"]
    assert axis["median"] == pytest.approx(0.35) and axis["worst"] == pytest.approx(0.6)
    assert axis["spread"] == pytest.approx(0.5) and not axis["worst_passes"]
    # each run in its own folder, the cache shared, the merged report on disk
    for s in range(6):
        run = tmp_path / "runs" / f"pliers-seed{s}"
        assert (run / f"ran-{s}.txt").is_file()
        assert json.loads((run / "results.json").read_text())["scenes"]["pliers"][
            "joints"][0]["axis_angle_deg"] == pytest.approx(0.1 * (s + 1))
        assert (run / "cache").resolve() == (tmp_path / "cache").resolve()
    on_disk = json.loads((tmp_path / "results.json").read_text())
    assert [r["status"] for r in on_disk["runs"]] == [r["status"] for r in res["runs"]]
    assert on_disk["meta"]["seeds"] == list(range(6))
    md = (tmp_path / "results.md").read_text()
    assert "**5 of 6 runs passed every gate.**" in md and "pliers seed 5" in md
    assert (tmp_path / "sweep_errors.png").stat().st_size > 1000


def test_one_seed_keeps_the_main_jobs_results_schema(tmp_path):
    """One run per scene: results.json as the main job always wrote it (``scenes``, ``meta``
    with ``seed``), pictures in OUT, whatever the number of jobs."""
    out = {}
    for jobs in (1, 2):
        out[jobs] = sweep.run_sweep(_specs(seeds=(2,)), tmp_path / f"j{jobs}",
                                    sweep.SweepConfig(jobs=jobs, progress=False),
                                    run_fn=light_run)
        assert set(out[jobs]) == {"schema_version", "scenes", "meta"}
        assert list(out[jobs]["scenes"]) == ["pliers", "truck"]
        assert out[jobs]["meta"]["seed"] == 2
        assert (tmp_path / f"j{jobs}" / "ran-2.txt").is_file()  # OUT is each run's folder
        assert not (tmp_path / f"j{jobs}" / "sweep_errors.png").exists()
    strip = [{n: {k: v for k, v in r.items() if k != "wall_s"} for n, r in o["scenes"].items()}
             for o in out.values()]
    assert strip[0] == strip[1]


def test_worker_that_dies_once_is_retried_and_every_run_is_listed(tmp_path):
    res = sweep.run_sweep(_specs(seeds=(0, 1, 2), scenes=("pliers",)), tmp_path,
                          sweep.SweepConfig(jobs=2, progress=False), run_fn=dying_run)
    assert [r["status"] for r in res["runs"]] == ["passed"] * 3
    assert [r["attempts"] for r in res["runs"]] == [1, 2, 1]
    assert (tmp_path / "runs" / "pliers-seed1" / "died-once").is_file()
    # the same figures as a sweep whose workers never died
    calm = sweep.run_sweep(_specs(seeds=(0, 1, 2), scenes=("pliers",)), tmp_path / "calm",
                           sweep.SweepConfig(progress=False), run_fn=light_run)
    assert _stable(res) == _stable(calm)


def test_worker_that_always_dies_is_reported_failed_not_missing(tmp_path, capsys):
    res = sweep.run_sweep(_specs(seeds=(0, 1), scenes=("pliers",)), tmp_path,
                          sweep.SweepConfig(jobs=2, progress=False), run_fn=always_dying_run)
    died = res["runs"][1]
    assert died["status"] == "died" and died["attempts"] == 2
    assert "exit code 4" in died["result"]["error"]
    assert died["result"]["failed_gates"][0]["gate"] == "error"
    assert cli.finish(record.Results.from_json(res)) == 1
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("FAIL: 1 of 2 run(s)") and "pliers seed 1 (worker died)" in last


def test_a_run_that_raises_is_failed_with_its_error_not_retried(tmp_path):
    res = sweep.run_sweep(_specs(seeds=(0,), scenes=("pliers", "truck")), tmp_path,
                          sweep.SweepConfig(progress=False), run_fn=raising_run)
    for r in res["scenes"].values():
        assert r["error"] == "worker: the run raised: RuntimeError: not the harness"
        assert not r["passed"] and "attempts" not in r


def test_resume_skips_finished_runs_and_reruns_changed_or_dead_ones(tmp_path):
    specs = _specs(seeds=(0, 1, 2), scenes=("pliers",))
    first = sweep.run_sweep(specs, tmp_path, sweep.SweepConfig(progress=False),
                            run_fn=light_run)
    # nothing to do: a run function that raises is never called
    again = sweep.run_sweep(specs, tmp_path, sweep.SweepConfig(progress=False, resume=True),
                            run_fn=raising_run)
    assert _stable(again) == _stable(first)
    # a record of other settings and a dead run are run again; the rest is kept
    rec_path = tmp_path / "runs" / "pliers-seed0" / "run.json"
    rec = json.loads(rec_path.read_text())
    rec["spec"]["config"]["views"] = 36
    rec_path.write_text(json.dumps(rec))
    rec_path = tmp_path / "runs" / "pliers-seed2" / "run.json"
    rec = json.loads(rec_path.read_text())
    rec["status"] = "died"
    rec_path.write_text(json.dumps(rec))
    third = sweep.run_sweep(specs, tmp_path, sweep.SweepConfig(progress=False, resume=True),
                            run_fn=raising_run)
    assert [r["status"] for r in third["runs"]] == ["failed", "passed", "failed"]
    assert "not the harness" in third["runs"][0]["result"]["error"]
    assert third["runs"][1] == first["runs"][1]


@pytest.mark.parametrize("change, why", [
    (lambda d: d.update(schema_version=0), "is of schema_version 0"),
    (lambda d: d.pop("schema_version"), "has no schema_version"),
    (lambda d: d.update(note="by hand"), "'note' is not a key of RunRecord"),
    (lambda d: d["result"]["joints"][0].update(axis_angle_deg="0.1"),
     "joints[0].axis_angle_deg: expected float, got str '0.1'"),
])
def test_resume_runs_again_a_record_it_cannot_read_and_says_why(tmp_path, caplog, change, why):
    """A run.json of another schema_version, of none (written before run.json had one), or with
    a key or value the record does not hold is neither trusted nor fatal: that run runs again,
    a warning names the run, the file and why; the others are kept."""
    specs = _specs(seeds=(0, 1), scenes=("pliers",))
    first = sweep.run_sweep(specs, tmp_path, sweep.SweepConfig(progress=False),
                            run_fn=light_run)
    path = tmp_path / "runs" / "pliers-seed0" / "run.json"
    data = json.loads(path.read_text())
    assert data["schema_version"] == record.SCHEMA_VERSION
    change(data)
    path.write_text(json.dumps(data))
    with caplog.at_level("WARNING", logger="sim.evaluate.sweep"):
        again = sweep.run_sweep(specs, tmp_path,
                                sweep.SweepConfig(progress=False, resume=True),
                                run_fn=raising_run)
    assert [r["status"] for r in again["runs"]] == ["failed", "passed"]  # run 0 ran again
    assert "not the harness" in again["runs"][0]["result"]["error"]
    assert again["runs"][1] == first["runs"][1]
    (warning,) = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert warning.startswith("resume: running pliers-seed0 again: its record is not one this "
                              f"code reads: {path}")
    assert why in warning
    assert record.read_run(path).status == "failed"  # written again, by this code's record


def _interrupting_run(name, ev, out_dir):
    if ev.seed == 1:
        raise KeyboardInterrupt
    return light_run(name, ev, out_dir)


def test_interrupted_sweep_lists_unfinished_runs_as_not_run(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        sweep.run_sweep(_specs(seeds=(0, 1, 2), scenes=("pliers",)), tmp_path,
                        sweep.SweepConfig(progress=False), run_fn=_interrupting_run)
    runs = json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [r["status"] for r in runs] == ["passed", "not run", "not run"]


# ---------------------------------------------------------------------------- command line


def test_command_line_sweep_verdict_names_runs_and_gates(tmp_path, monkeypatch, capsys):
    real = sweep.run_sweep

    def light_sweep(specs, out_dir, cfg=None, argv=None, **kw):
        assert [s.config.seed for s in specs] == [0, 1, 2, 3, 4, 5]
        return real(specs, out_dir, cfg, run_fn=light_run, argv=argv, **kw)

    monkeypatch.setattr(sweep, "run_sweep", light_sweep)
    argv = ["pliers", "--seeds", "0-5", "--no-manipulate", "--out", str(tmp_path), "--quiet"]
    assert cli.main(argv) == 1
    out = capsys.readouterr()
    last = out.out.strip().splitlines()[-1]
    assert last == "FAIL: 1 of 6 run(s) missed a gate or failed: pliers seed 5 (axis_angle_deg)"
    assert "FAIL pliers seed 5: hinge: axis_angle_deg" in out.err
    assert "pliers-seed5" in out.out  # the table lists every run
    assert cli.main([*argv, "--report-only", "--resume"]) == 0


def test_ctrl_c_prints_one_line_and_exits_130(tmp_path, monkeypatch, capsys):
    def interrupted(*a, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "run_sweep", interrupted)
    assert cli.main(["pliers", "--seeds", "0-1", "--out", str(tmp_path), "--quiet"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("interrupted:") and "--resume" in err[0]


@pytest.mark.parametrize("argv, message", [
    (["--address", "auto"], "--backend ray"),
    (["--seed", "1", "--seeds", "0-2"], "either --seed or --seeds"),
    (["--seeds", "4-2"], "not a seed or a range"),
    (["--jobs", "0"], "whole number >= 1"),
])
def test_command_line_refuses_bad_sweep_options(argv, message, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["pliers", "--out", str(tmp_path), *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_missing_ray_names_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(SystemExit) as exc:
        cli.main(["pliers", "--backend", "ray", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert 'pip install -e ".[ray]"' in capsys.readouterr().err
    with pytest.raises(sweep.SweepError, match=r"\.\[ray\]"):
        sweep.run_sweep(_specs(seeds=(0,)), tmp_path,
                        sweep.SweepConfig(backend="ray", progress=False), run_fn=light_run)


# ---------------------------------------------------------------------------- Ray


def test_ray_sweep_gives_the_process_pools_results_and_retries_a_dead_worker(tmp_path):
    """A local Ray cluster (num_cpus=2, started by the sweep) and the process pool run the same
    sweep; the merged results are equal. On Ray the first worker of seed 1 dies: retried."""
    ray = pytest.importorskip("ray", reason='the Ray extra: pip install -e ".[ray]"')
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers lack tests/
    try:
        specs = _specs(seeds=(0, 1), scenes=("pliers", "truck"))
        on_ray = sweep.run_sweep(specs, tmp_path / "ray",
                                 sweep.SweepConfig(backend="ray", jobs=2, progress=False),
                                 run_fn=dying_run)
    finally:
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert not ray.is_initialized()  # the sweep shut down the cluster it started
    pool = sweep.run_sweep(specs, tmp_path / "pool", sweep.SweepConfig(jobs=2, progress=False),
                           run_fn=light_run)
    assert _stable(on_ray) == _stable(pool)
    assert [r["attempts"] for r in on_ray["runs"]] == [1, 2, 1, 2]
    assert on_ray["meta"]["sweep"]["backend"] == "ray"


# ---------------------------------------------------------------------------- the harness


@pytest.mark.slow
def test_real_sweep_on_two_worker_processes(tmp_path):
    """The harness itself, two seeds of pliers (8 views per ring, no manipulation) on two worker
    processes: both runs in the merged report with the results of their own folders, each seed
    its own captures in the one shared cache, each worker's output in its run's log; run again
    with --resume, nothing runs and the report is the same. (About 2 x 100 s of CPU.)"""
    argv = ["pliers", "--seeds", "0-1", "--views", "8", "--no-manipulate", "--jobs", "2",
            "--out", str(tmp_path), "--quiet", "--report-only"]
    assert cli.main(argv) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    assert [r["id"] for r in results["runs"]] == ["pliers-seed0", "pliers-seed1"]
    for rec in results["runs"]:
        res = rec["result"]
        assert rec["status"] in ("passed", "failed") and rec["attempts"] == 1
        assert res["scene_hash"] and res["error_stage"] != "worker"  # the harness ran
        own = json.loads((tmp_path / rec["dir"] / "results.json").read_text())
        assert own["scenes"]["pliers"] == res and own["meta"]["seed"] == rec["spec"][
            "config"]["seed"]
        assert (tmp_path / rec["dir"] / "log.txt").is_file()
    assert len(list((tmp_path / "cache").glob("capture_a-*"))) == 2  # captured in the workers
    assert not list((tmp_path / "cache").glob(".*"))  # no work folder, no lock file left
    before = (tmp_path / "results.json").stat().st_mtime_ns
    assert cli.main([*argv, "--resume"]) == 0
    again = json.loads((tmp_path / "results.json").read_text())
    assert again["runs"] == results["runs"]
    assert (tmp_path / "results.json").stat().st_mtime_ns >= before


# ---------------------------------------------------------------------------- the stage cache


def _build_demo(folder: Path) -> dict:
    """A stage that takes a while and writes two files; each build leaves a line in a log."""
    with open(folder.parent / "builds.log", "a") as fh:
        fh.write(f"{os.getpid()}\n")
    (folder / "a.txt").write_text("a" * 10000)
    time.sleep(1.0)
    (folder / "b.txt").write_text("b" * 10000)
    return {"pid": os.getpid()}


def _cache_worker(root: str, barrier, queue) -> None:
    barrier.wait()
    folder, meta, hit = cache.cached_stage(root, "demo", {"x": 1}, _build_demo)
    queue.put((str(folder), meta["pid"], hit, sorted(p.name for p in Path(folder).iterdir())))


def _cache_reader(root: str, barrier, queue) -> None:
    """Look at the stage folder as often as possible while it is built: whenever it counts as
    cached, every file must be there, whole."""
    barrier.wait()
    seen_partial, looks = False, 0
    t_end = time.time() + 6.0
    while time.time() < t_end:
        if cache.is_cached(root, "demo", {"x": 1}):
            looks += 1
            folder = Path(root) / cache.stage_key("demo", {"x": 1})
            a, b = folder / "a.txt", folder / "b.txt"
            if not (a.is_file() and b.is_file() and len(b.read_text()) == 10000):
                seen_partial = True
            if looks > 50:
                break
    queue.put(("reader", seen_partial, looks))


def _builder_that_dies(root: str) -> None:
    def build(folder):
        (folder / "a.txt").write_text("half")
        os._exit(1)

    cache.cached_stage(root, "demo", {"x": 1}, build)


def test_two_processes_building_the_same_stage_build_it_once_and_never_half_read(tmp_path):
    ctx = multiprocessing.get_context("spawn")
    root = str(tmp_path / "cache")
    # a builder killed half-way leaves no stage and no lock held
    p = ctx.Process(target=_builder_that_dies, args=(root,))
    p.start()
    p.join()
    assert p.exitcode == 1 and not cache.is_cached(root, "demo", {"x": 1})
    barrier, queue = ctx.Barrier(3), ctx.Queue()
    procs = [ctx.Process(target=_cache_worker, args=(root, barrier, queue)) for _ in range(2)]
    procs.append(ctx.Process(target=_cache_reader, args=(root, barrier, queue)))
    for p in procs:
        p.start()
    got = [queue.get(timeout=120) for _ in procs]
    for p in procs:
        p.join()
    workers = [g for g in got if g[0] != "reader"]
    (reader,) = [g for g in got if g[0] == "reader"]
    assert {w[0] for w in workers} == {str(Path(root) / cache.stage_key("demo", {"x": 1}))}
    assert sorted(w[2] for w in workers) == [False, True]  # one built it, the other read it
    assert workers[0][1] == workers[1][1]  # the same build's metadata
    assert all(w[3] == ["a.txt", "b.txt", "stage.json"] for w in workers)
    assert (tmp_path / "cache" / "builds.log").read_text().count("\n") == 1  # built once
    assert reader[1] is False and reader[2] > 0
    # nothing left over but the stage and the build log: no work folder, no lock file
    left = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert left == sorted([cache.stage_key("demo", {"x": 1}), "builds.log"])


# ---------------------------------------------------------------------------- pictures


def test_strength_chart_draws_runs_against_the_perturbation(tmp_path):
    specs = [sweep.RunSpec("pliers", EvalConfig(seed=s, manipulate=False), label="baseline")
             for s in (0, 1)]
    specs += [sweep.RunSpec("pliers", EvalConfig(seed=s, manipulate=False,
                                                 perturb=Perturbation(image_noise_sigma=n)),
                            perturbation="noise", strength=n, label=f"noise_{n}")
              for n in (4, 12) for s in (0, 1)]
    axis = {"title": "image noise", "unit": "grey levels", "neutral": 0}
    sweep.run_sweep(specs, tmp_path, sweep.SweepConfig(progress=False), run_fn=light_run,
                    perturbations={"noise": axis})
    results = record.read_results(tmp_path / "results.json")
    pts = pictures._axis_points(results, "noise", axis)
    assert [x for x, _ in pts] == [0, 0, 4, 4, 12, 12]
    # the strength reaches the run: 0.01 deg of axis error per grey level of noise
    assert [r.result.joints[0].axis_angle_deg for _, r in pts] == pytest.approx(
        [0.1, 0.2, 0.14, 0.24, 0.22, 0.32])
    assert (tmp_path / "sweep_noise.png").stat().st_size > 1000
    assert "![noise](sweep_noise.png)" in (tmp_path / "results.md").read_text()
    img = pictures.draw_strength_chart(results, "noise", axis)
    assert img.shape == (340, 920, 3) and (img != 255).any()
