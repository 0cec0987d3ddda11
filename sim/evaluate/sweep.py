"""Sweeps: many scene runs (scene x seed x settings x perturbation), in parallel, merged.

A **run** is one scene evaluated with one :class:`~sim.evaluate.config.EvalConfig` (its seed and
perturbation included): :class:`RunSpec`. :func:`run_sweep` runs a list of them and merges their
results into one ``results.json`` / ``results.md`` (:mod:`sim.evaluate.report`). The unit of work
is :func:`sim.evaluate.runner.evaluate_scene` (or a function with its signature, for tests),
then the run's pictures; where it runs is the backend's business (:class:`SweepConfig`):

- ``jobs=1`` (the default): one run after the other in this process, as the main job always ran;
- ``jobs=N``: N worker processes at a time on this machine, each run in a fresh process of its
  own (spawned: its own MuJoCo and OpenGL context; no server, nothing to install);
- ``backend="ray"``: the same tasks on a Ray cluster (``pip install -e ".[ray]"``), an existing one
  at ``address`` or a local one started for the sweep (``num_cpus=jobs``). Every node must see the
  output folder at the same path (a shared file system) and have this project installed.

Layout of the output folder ``OUT``:

- ``OUT/cache/``: the stage cache shared by every run (:mod:`sim.cache`: written atomically,
  locked per stage, so concurrent workers never build a stage twice or read half of one);
- ``OUT/runs/<run id>/run.json``: each finished run's record (its spec, status, attempts, worker,
  result; :class:`sim.evaluate.record.RunRecord` with the schema_version), written whole when the
  run ends: what ``resume`` reads;
- one run per scene (the main job's default: one seed): the pictures and ``results.json`` in
  ``OUT`` exactly as before (``{"scenes": {name: result}, "meta": ...}``);
- a sweep (several runs of a scene: seeds, perturbations): each run's own report folder
  ``OUT/runs/<run id>/`` (``results.json``, ``results.md``, pictures, ``log.txt``; its ``cache``
  links to ``OUT/cache``) and in ``OUT`` the merged ``results.json`` (``runs``: every run with its
  status, ``summary``: per scene and setting the median, worst and spread over seeds),
  ``results.md`` and the sweep's pictures.

A run whose worker dies (killed, out of memory, a crash in native code) is run again once
(:attr:`SweepConfig.retries`) and then recorded as failed (``status: "died"``): every run of the
sweep is in the merged results, finished or not (``"not run"`` while a sweep is under way or
after an interruption). A run that raises is recorded as failed with its error, not retried (it
would raise again). With ``resume``, runs whose record holds the same spec and code are taken
from it, not run again; a record this code cannot take as it stands (unreadable, not JSON, of
another schema_version or with a key or value :mod:`sim.evaluate.record` does not hold) is not
trusted and not fatal: its run is run again, and a warning names the file and why. Figures that
were not written by this code's record could not be merged into the results anyway, and running
the run again is what the user asked ``--resume`` for: a complete sweep.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import os
import re
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

import artrecon
import sim
from artrecon.files import write_json_atomic
from sim import cache
from sim.evaluate import gates, record, report, sweep_report
from sim.evaluate.backends import RAY_EXTRA, SweepError, execute, make_backend  # noqa: F401
from sim.evaluate.config import EvalConfig
from sim.evaluate.runner import evaluate_scene, run_meta

log = logging.getLogger(__name__)

#: Where runs can run (:attr:`SweepConfig.backend`).
BACKENDS = ("local", "ray")
#: Fields of EvalConfig that do not change a run's figures (left out of its spec).
NON_RESULT_FIELDS = ("progress", "parallel_capture")
#: Statuses of a run in the merged results.
STATUSES = ("passed", "failed", "died", "not run")


@dataclass(frozen=True)
class RunSpec:
    """One scene run of a sweep."""

    scene: str
    """bundled scene name or MJCF path"""
    config: EvalConfig = field(default_factory=EvalConfig)
    """the run's settings, its seed and perturbation included"""
    perturbation: str = ""
    """the perturbation this run varies, for robustness sweeps (``""``: none); its runs are drawn
    against their :attr:`strength`"""
    strength: float | None = None
    """the strength of :attr:`perturbation` (the unperturbed baseline: its neutral value)"""
    label: str = ""
    """what tells this run apart from other runs of the same scene and seed (e.g.
    ``noise_4``); part of its id"""

    @property
    def scene_id(self) -> str:
        """The scene part of the run's id: the bundled name or the file's stem."""
        s = self.scene
        return _safe(Path(s).stem if s.endswith(".xml") else s)

    @property
    def group(self) -> str:
        """Runs that differ only by seed share a group (the rows of the summary)."""
        return self.scene_id + (f"-{_safe(self.label)}" if self.label else "")

    @property
    def run_id(self) -> str:
        """The run's folder name under ``OUT/runs``: scene, seed, label."""
        return (f"{self.scene_id}-seed{self.config.seed}"
                + (f"-{_safe(self.label)}" if self.label else ""))

    def describe(self) -> dict:
        """The spec as JSON: what decides the run's figures (compared on resume)."""
        ev = {f.name: getattr(self.config, f.name) for f in dataclasses.fields(self.config)
              if f.name not in NON_RESULT_FIELDS}
        ev = {k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v
              for k, v in ev.items()}
        ev["perturb"] = self.config.perturb.changed()
        del ev["capture_settings"]  # named only when set: a default run's spec keeps its keys
        settings = self.config.capture_settings.changed()
        if settings:
            ev["capture_settings"] = settings
        return report._clean({"scene": self.scene, "config": ev, "perturbation": self.perturbation,
                       "strength": self.strength, "label": self.label})


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.]+", "_", str(text)).strip("_") or "run"


@dataclass(frozen=True)
class SweepConfig:
    """How a sweep's runs are run."""

    jobs: int | None = None
    """runs at once: local backend 1 (default: in this process, one after the other) or N worker
    processes; Ray: at most N in flight (default: as many as the cluster takes), and the CPUs of a
    local cluster started for the sweep"""
    backend: str = "local"
    """``"local"`` (this machine) or ``"ray"`` (a Ray cluster)"""
    address: str | None = None
    """Ray: the address of an existing cluster (``auto``, ``HOST:PORT``, ``ray://HOST:10001``);
    None starts a local one for the sweep"""
    retries: int = 1
    """how often a run whose worker died is run again before it is recorded as failed"""
    resume: bool = False
    """take runs that finished before (same spec, same code) from their records"""
    progress: bool = True
    """the overall progress bar (runs done, failed, time left)"""

    def __post_init__(self) -> None:
        if self.backend not in BACKENDS:
            raise ValueError(f"SweepConfig.backend must be one of {BACKENDS}, got "
                             f"{self.backend!r}")
        if self.jobs is not None and self.jobs < 1:
            raise ValueError(f"SweepConfig.jobs must be at least 1, got {self.jobs}")
        if self.address and self.backend != "ray":
            raise ValueError("SweepConfig.address is the address of a Ray cluster: it needs "
                             "backend 'ray'")
        if self.retries < 0:
            raise ValueError(f"SweepConfig.retries must be >= 0, got {self.retries}")

    @property
    def inline(self) -> bool:
        """Whether runs run in this process (local backend, one job)."""
        return self.backend == "local" and (self.jobs or 1) == 1


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-4"``, ``"0,2,7"``, ``"0-2,9"`` (ranges inclusive), in the order given,
    without repeats.

    Raises
    ------
    ValueError
        A part that is not a non-negative integer or ``A-B`` with ``A <= B``.
    """
    seeds: list[int] = []
    for part in str(text).replace(" ", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m or (m.group(2) is not None and int(m.group(2)) < int(m.group(1))):
            raise ValueError(f"seeds {text!r}: {part!r} is not a seed or a range A-B (A <= B); "
                             "write e.g. 0-4 or 0,2,7")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        seeds += [s for s in range(lo, hi + 1) if s not in seeds]
    return seeds


def plan(names: Iterable[str], ev: EvalConfig, seeds: Iterable[int] | None = None
         ) -> list[RunSpec]:
    """The runs of scenes x seeds at the settings ``ev`` (default seeds: ``ev.seed``), scene by
    scene."""
    seeds = list(seeds) if seeds is not None else [ev.seed]
    return [RunSpec(name, dataclasses.replace(ev, seed=s)) for name in names for s in seeds]


def code_hash() -> str:
    """Hash of the source of ``artrecon`` and ``sim``: a run recorded under another one is run
    again on resume (its figures may have changed)."""
    return cache.source_hash([artrecon, sim])[:16]


# ---------------------------------------------------------------------------- the sweep


def run_sweep(specs: list[RunSpec], out_dir: Path, sweep: SweepConfig | None = None,
              run_fn: Callable[[str, EvalConfig, Path], dict] | None = None,
              argv: list[str] | None = None, layout: str | None = None,
              command: str | None = None, perturbations: dict[str, dict] | None = None
              ) -> dict:
    """Run every spec and write the merged report into ``out_dir``; returns the merged results.

    Parameters
    ----------
    specs : list of RunSpec
        The runs (ids must be unique: scene, seed and label).
    out_dir : path
        The output folder (see the module's docstring for its layout).
    sweep : SweepConfig
        Backend, jobs, retries, resume, progress (default: one after the other, here).
    run_fn : callable
        ``run_fn(scene, ev, out_dir) -> result``, :func:`sim.evaluate.runner.evaluate_scene`
        by default (tests give a light one; it must be importable by the workers).
    argv : list of str
        The command line, for the report.
    layout : {"scenes", "sweep"}
        ``"scenes"``: one run per scene, written as the main job always wrote
        (``results.json`` ``scenes``); ``"sweep"``: runs and summary. Default: ``"scenes"``
        when every run is of another scene at the same settings, else ``"sweep"``.
    command : str
        The command named in the report (default ``python -m sim.evaluate`` + argv).
    perturbations : dict
        Robustness sweeps: ``{name: {"title", "unit", "neutral"}}`` of the perturbations that
        the runs' :attr:`RunSpec.perturbation` name; the report draws each one's errors
        against its strength, the unperturbed runs at ``neutral`` (None: left out).

    Returns
    -------
    dict
        The merged ``results.json``.

    Raises
    ------
    SweepError
        The backend cannot start (Ray missing or unreachable), or two runs share an id.
    KeyboardInterrupt
        After ending the workers and writing what finished.
    """
    sweep = sweep or SweepConfig()
    run_fn = run_fn or evaluate_scene
    out = Path(out_dir)
    specs = list(specs)
    if not specs:
        raise SweepError("nothing to run: no scenes")
    ids = [s.run_id for s in specs]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise SweepError(f"runs {dup} appear twice (same scene, seed and label): give each a "
                         "label of its own")
    if layout is None:
        same = all(s.describe()["config"] == specs[0].describe()["config"] for s in specs)
        layout = ("scenes" if same and len({s.scene_id for s in specs}) == len(specs)
                  and not any(s.label or s.perturbation for s in specs) else "sweep")
    if layout not in ("scenes", "sweep"):
        raise ValueError(f"layout must be 'scenes' or 'sweep', got {layout!r}")
    command = command or " ".join(["python -m sim.evaluate", *(argv or [])])
    out.mkdir(parents=True, exist_ok=True)
    (out / "cache").mkdir(exist_ok=True)
    code = code_hash()
    state = _State(specs, out, layout, sweep, command, code, run_fn)
    state.perturbations = perturbations

    todo = []
    for spec in specs:
        old = state.recorded(spec) if sweep.resume else None
        if old is not None:
            state.records[spec.run_id] = old
        else:
            todo.append(spec)
    if sweep.resume:
        log.info("resume: %d of %d runs finished before", len(specs) - len(todo), len(specs))
    backend = make_backend(sweep)  # may raise SweepError before anything ran
    bar = tqdm(total=len(specs), initial=len(specs) - len(todo), desc="runs", unit="run",
               disable=not sweep.progress, dynamic_ncols=True)
    bar.set_postfix(failed=state.n_failed(), refresh=False)
    if layout == "sweep" or state.records:  # a sweep lists its runs from the start; the main
        state.write()  # job's report is replaced only when a run has finished, as before
    queue = collections.deque((spec, 1) for spec in todo)
    live: dict = {}
    t0 = time.perf_counter()
    try:
        while queue or live:
            while queue and len(live) < backend.capacity:
                spec, attempt = queue.popleft()
                live[backend.submit(state.task(spec, attempt, inline=sweep.inline))] = (spec,
                                                                                        attempt)
            for handle, outcome in backend.wait(list(live)):
                spec, attempt = live.pop(handle)
                if outcome["status"] == "died" and attempt <= sweep.retries:
                    log.warning("%s: %s (attempt %d); running it again", spec.run_id,
                                outcome["error"], attempt)
                    queue.appendleft((spec, attempt + 1))
                    continue
                state.finish(spec, attempt, outcome)
                bar.update(1)
                bar.set_postfix(failed=state.n_failed())
        state.wall_s = time.perf_counter() - t0
    except BaseException:
        backend.close(cancel=True)
        bar.close()
        state.wall_s = time.perf_counter() - t0
        state.write()  # what finished is kept, the rest is listed as not run
        raise
    backend.close()
    bar.close()
    return state.write()


class _State:
    """The records of a sweep's runs and the merged results written from them."""

    def __init__(self, specs, out, layout, sweep, command, code, run_fn):
        self.specs, self.out, self.layout, self.sweep = specs, out, layout, sweep
        self.command, self.code, self.run_fn = command, code, run_fn
        self.records: dict[str, record.RunRecord] = {}
        self.wall_s: float | None = None
        self.perturbations: dict | None = None

    def run_dir(self, spec: RunSpec) -> Path:
        return self.out / "runs" / spec.run_id

    def recorded(self, spec: RunSpec) -> record.RunRecord | None:
        """The finished record of ``spec`` if it holds the same spec and code (resume); None
        (the run runs again) when it does not, or when its run.json is unreadable or not of
        this code's record (:func:`sim.evaluate.record.read_run`: a warning says why)."""
        path = self.run_dir(spec) / "run.json"
        if not path.is_file():
            return None
        try:
            rec = record.read_run(path)
        except OSError as err:
            log.warning("resume: %s unreadable (%s): running %s again", path, err, spec.run_id)
            return None
        except record.SchemaError as err:
            log.warning("resume: running %s again: its record is not one this code reads: %s",
                        spec.run_id, err)
            return None
        why = ("its spec differs" if rec.spec is None or rec.spec.to_json() != spec.describe()
               else "the code changed since" if rec.code != self.code else
               "its worker died" if rec.status == "died" else None)
        if why:
            log.info("resume: running %s again: %s", spec.run_id, why)
            return None
        return rec

    def task(self, spec: RunSpec, attempt: int, inline: bool) -> dict:
        ev = spec.config
        if not inline:  # one progress bar (the sweep's), one process per run
            ev = dataclasses.replace(ev, progress=False, parallel_capture=False)
        run_dir = self.run_dir(spec)
        run_dir.mkdir(parents=True, exist_ok=True)
        if self.layout == "sweep":
            link = run_dir / "cache"
            if not link.is_symlink() and not link.exists():
                os.symlink(os.path.relpath(self.out / "cache", run_dir), link)
            work, pictures = run_dir, run_dir
        else:
            work, pictures = self.out, self.out
        return {"spec": dataclasses.replace(spec, config=ev), "run_dir": str(work),
                "picture_dir": str(pictures), "report": self.layout == "sweep",
                "log": None if inline else str(run_dir / "log.txt"),
                "run_fn": self.run_fn, "command": self.command, "attempt": attempt}

    def finish(self, spec: RunSpec, attempts: int, outcome: dict) -> record.RunRecord:
        """Record a run that ended (its result, or a failure that stands for it)."""
        if outcome["status"] == "done":
            result = outcome["result"]
        else:
            what = ("worker died" if outcome["status"] == "died" else "the run raised")
            result = {"scene": spec.scene_id, "error": f"worker: {what}: {outcome['error']}"
                      + (f" (on each of {attempts} attempts)" if attempts > 1 else ""),
                      "error_stage": "worker", "traceback": outcome.get("traceback")}
            v = gates.verdict(result, manipulate=spec.config.manipulate)
            result.update(passed=v["passed"], failed_gates=v["failed"])
        status = ("died" if outcome["status"] == "died" else
                  "passed" if result.get("passed") and not result.get("error") else "failed")
        if attempts > 1:
            result["attempts"] = attempts
        path = self.run_dir(spec) / "run.json"
        rec = record.RunRecord.from_json(report._clean({
            "id": spec.run_id, "group": spec.group, "spec": spec.describe(), "code": self.code,
            "status": status, "attempts": attempts,
            "worker": {k: outcome.get(k) for k in ("host", "pid", "wall_s")},
            "dir": os.path.relpath(self.run_dir(spec), self.out), "result": result}), str(path))
        write_json_atomic(path, record.run_file(rec))
        self.records[spec.run_id] = rec
        self.write()
        return rec

    def n_failed(self) -> int:
        return sum(r.status in ("failed", "died") for r in self.records.values())

    def write(self) -> dict:
        """The merged results.json, results.md and pictures, from the records so far; returns
        the JSON written (:mod:`sim.evaluate.record`)."""
        base = self.specs[0].config
        meta = run_meta(base, self.command)
        if self.sweep.backend != "local" or (self.sweep.jobs or 1) > 1 or self.layout == "sweep":
            meta["sweep"] = {"backend": self.sweep.backend, "jobs": self.sweep.jobs,
                             "address": self.sweep.address, "retries": self.sweep.retries,
                             "runs": len(self.specs), "wall_s": self.wall_s}
        done = [self.records[s.run_id] for s in self.specs if s.run_id in self.records]
        for rec in done:
            meta["scene_hashes"][rec.result.scene] = rec.result.scene_hash
        if self.layout == "scenes":
            results = {"scenes": {rec.result.scene: rec.result.to_json() for rec in done},
                       "meta": meta}
            return report.write_results(results, self.out)
        meta["seeds"] = sorted({s.config.seed for s in self.specs})
        del meta["seed"]
        if self.perturbations:
            meta["perturbations"] = self.perturbations
        runs = []
        for spec in self.specs:
            rec = self.records.get(spec.run_id)
            if rec is None:  # no code: it did not run
                rec = record.RunRecord.from_json(report._clean({
                    "id": spec.run_id, "group": spec.group, "spec": spec.describe(),
                    "status": "not run", "attempts": 0, "worker": None,
                    "dir": os.path.relpath(self.run_dir(spec), self.out), "result": None}))
            runs.append(rec)
        results = record.Results(meta=record.Meta.from_json(report._clean(meta)), runs=runs,
                                 summary=sweep_report.sweep_summary(runs))
        return sweep_report.write_sweep(results, self.out)


def run(names: list[str], ev: EvalConfig, out_dir: Path, argv: list[str] | None = None) -> dict:
    """Evaluate scenes and write the report folder. Returns the results dict (results.json).

    One run per scene at the settings ``ev``, one after the other in this process: the trivial
    sweep (:func:`run_sweep`, which runs seeds and perturbations in parallel).
    """
    return run_sweep(plan(names, ev), out_dir, SweepConfig(progress=ev.progress), argv=argv)
