"""Faults: a command killed (SIGKILL) or interrupted (Ctrl-C: SIGINT to its process group, as a
terminal sends it) mid-run leaves the old result intact and no half-written file under a real
name; Ctrl-C prints one line and exits 130; a rerun finishes. Run as subprocesses."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from badinput import REPO, tree
from test_export import synthetic_model

from artrecon import files


def _default_sigint() -> None:
    """In the child: Ctrl-C's default disposition. A suite started in the background of a
    non-interactive shell inherits SIGINT ignored, and Python keeps an ignored SIGINT ignored:
    the command would never see the Ctrl-C this file sends it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(argv: list[str]) -> subprocess.Popen:
    """A command in its own process group (so a signal reaches it and its workers together)."""
    return subprocess.Popen([sys.executable, "-m", *argv], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=_default_sigint)


def _wait_for(found, proc: subprocess.Popen, timeout: float = 300.0, poll: float = 0.05):
    """Poll ``found()`` until it returns something truthy (returned) while ``proc`` runs."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        hit = found()
        if hit:
            return hit
        if proc.poll() is not None:
            raise AssertionError(f"the command ended early ({proc.returncode}): "
                                 f"{proc.stderr.read().decode()[-2000:]}")
        time.sleep(poll)
    raise AssertionError("timed out waiting for the command to get there")


def _signal(proc: subprocess.Popen, sig) -> tuple[int, str]:
    os.killpg(proc.pid, sig)
    _, err = proc.communicate(timeout=300)
    return proc.returncode, err.decode()


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def _visible(t: dict) -> dict:
    """A tree snapshot without hidden entries (temporaries and work folders)."""
    return {k: v for k, v in t.items() if not any(part.startswith(".")
                                                  for part in Path(k).parts[-3:])}


def test_work_folders_get_the_usual_mode(tmp_path):
    """Output folders were published with mkdtemp's mode 0700."""
    out = tmp_path / "out"
    work = files.make_work_dir(out)
    (work / "model.json").write_text("{}")
    files.publish_dir(work, out)
    assert out.stat().st_mode & 0o777 == 0o777 & ~files.umask()


def test_an_interrupt_inside_make_work_dir_leaves_no_work_folder(tmp_path, monkeypatch):
    """CI, on a busy machine: Ctrl-C reached sim.capture after the work folder was made and before
    its name was returned, and the folder stayed. work_dir removes this process's work folders of
    OUT wherever the interrupt lands; another live run's and the published folder stay."""
    out = tmp_path / "out"
    other = tmp_path / f".out.tmp-{os.getppid()}-x"  # a live process's work folder (the parent)
    other.mkdir()

    def interrupted() -> int:  # called by make_work_dir after mkdtemp
        raise KeyboardInterrupt

    monkeypatch.setattr(files, "umask", interrupted)
    with pytest.raises(KeyboardInterrupt), files.work_dir(out):
        pytest.fail("the block must not run")
    assert sorted(p.name for p in tmp_path.iterdir()) == [other.name]
    monkeypatch.undo()
    with pytest.raises(RuntimeError), files.work_dir(out) as work:  # an error in the block
        (work / "model.json").write_text("{}")
        raise RuntimeError("stage failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == [other.name]
    with files.work_dir(out) as work:  # published: kept, nothing else left
        (work / "model.json").write_text("{}")
        files.publish_dir(work, out)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([other.name, "out"])
    assert (out / "model.json").is_file()


def test_killed_export_leaves_the_old_twin_and_a_rerun_finishes(tmp_path):
    _, model = synthetic_model(4, "chain", ("revolute", "prismatic"), 1.0, True)
    rng = np.random.default_rng(0)
    for lk in model.links:  # many points: meshing and writing take a while
        lk.points = np.concatenate([lk.points + 0.002 * rng.normal(size=lk.points.shape)
                                    for _ in range(40)])
        lk.match_indices = np.full(len(lk.points), -1)
        lk.colours = lk.normals = lk.observed_in = None
    path = model.save(tmp_path / "model.json")
    out = tmp_path / "twin" / "t.xml"
    argv = ["artrecon", "export", str(path), "--format", "mjcf", "--out", str(out)]
    assert subprocess.run([sys.executable, "-m", *argv, "--voxel-size", "0.02"], cwd=REPO,
                          capture_output=True).returncode == 0
    old = tree(tmp_path)
    proc = _start([*argv, "--voxel-size", "0.01", "--overwrite"])
    _wait_for(lambda: list(out.parent.rglob(".*.tmp")), proc, poll=0.005)
    code, _ = _signal(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert _visible(tree(tmp_path)) == _visible(old)  # every real name: the old bytes
    rerun = subprocess.run([sys.executable, "-m", *argv, "--voxel-size", "0.01", "--overwrite"],
                           cwd=REPO, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert not list(tmp_path.rglob(".*.tmp"))  # the killed run's temporaries are gone too
    assert tree(path) == {str(path): old[str(path)]}
    import mujoco

    mujoco.MjModel.from_xml_path(str(out))


@pytest.mark.slow
def test_killed_and_interrupted_reconstructions_keep_the_old_result(rendered, tmp_path):
    """SIGKILL, then Ctrl-C, mid-run of `artrecon reconstruct --overwrite` over an earlier
    result: the earlier result stays byte for byte, Ctrl-C prints one line and exits 130,
    and a third run replaces the result whole and leaves no work folder."""
    out = tmp_path / "model"
    _, old_model = synthetic_model(5, "pair", ("revolute",))
    old_model.save(out / "model.json")
    (out / "notes.txt").write_text("part of the earlier result")
    old = tree(out)
    argv = ["artrecon", "reconstruct", str(rendered["a"].folder), str(rendered["b"].folder),
            "--out", str(out), "--overwrite", "--use-poses", "--quiet"]

    def work_dirs():
        return [p for p in tmp_path.glob(".model.tmp-*") if (p / "a").is_dir()]

    killed = _start(argv)
    stale = _wait_for(work_dirs, killed)
    code, _ = _signal(killed, signal.SIGKILL)
    assert code == -signal.SIGKILL and tree(out) == old and stale[0].exists()

    interrupted = _start(argv)
    _wait_for(lambda: [p for p in work_dirs() if str(interrupted.pid) in p.name], interrupted)
    assert not stale[0].exists()  # removed by the next run, the killed one's
    code, err = _signal(interrupted, signal.SIGINT)
    assert code == 130 and "Traceback" not in err
    assert len(_lines(err)) == 1 and "interrupted" in err, err
    assert tree(out) == old and not list(tmp_path.glob(".model.tmp-*"))

    done = subprocess.run([sys.executable, "-m", *argv], cwd=REPO, capture_output=True,
                          text=True, timeout=1800)
    assert done.returncode == 0, done.stderr
    assert not (out / "notes.txt").exists() and (out / "links" / "link_0.ply").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    from artrecon.model import ArticulatedModel

    assert len(ArticulatedModel.load(out / "model.json").joints) == 1


def test_a_failed_configuration_stops_the_other_at_once(rendered, tmp_path, monkeypatch):
    """Configuration A fails while B still runs in the second process: the error reaches the
    user at once, B stopped (the pool's block waited for B's whole SfM and dense stereo
    first), and no result or work folder is left."""
    import importlib

    import slow_tasks

    from artrecon.errors import ReconstructionError

    rec = importlib.import_module("artrecon.reconstruct")  # the module, not its function

    mark = tmp_path / "b_finished"
    monkeypatch.setenv("ARTRECON_TEST_B_MARK", str(mark))

    def failing_a(*args):
        raise ReconstructionError("configuration A: SfM registered 3 of 36 images (test)")

    monkeypatch.setattr(rec, "_configuration", failing_a)
    monkeypatch.setattr(rec, "_configuration_in_process", slow_tasks.slow_configuration_b)
    with pytest.raises(ReconstructionError, match="registered 3 of 36"):
        rec.reconstruct(rendered["a"].folder, rendered["b"].folder, poses=True,
                        out_dir=tmp_path / "model", progress=False)
    assert not mark.exists(), "A's error waited for B to finish"
    assert not (tmp_path / "model").exists() and not list(tmp_path.glob(".model.tmp-*"))


def test_a_ctrl_c_a_library_swallowed_still_stops_the_work():
    """Within interrupts_remembered a SIGINT raises KeyboardInterrupt and is remembered: when a
    library drops the exception (PyOpenGL sees a Ctrl-C in its argument conversion as a
    ctypes.ArgumentError; a capture in CI ran on and published, exit status 0),
    raise_if_interrupted raises it again at the run's next check."""
    from artrecon import workers

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        workers.raise_if_interrupted()  # nothing yet
        with workers.interrupts_remembered():
            workers.raise_if_interrupted()
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1.0)  # the handler runs here
                raise AssertionError("no KeyboardInterrupt")
            except KeyboardInterrupt:
                pass  # a library's except that drops it
            with pytest.raises(KeyboardInterrupt):
                workers.raise_if_interrupted()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        with workers.interrupts_remembered():  # a new block starts afresh
            workers.raise_if_interrupted()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_interrupted_capture_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "a"
    proc = _start(["sim.capture", "pliers", "--config", "a", "--views", "8", "--out", str(out),
                   "--quiet"])
    _wait_for(lambda: [p for p in tmp_path.iterdir() if p.name.startswith(".a.")], proc)
    code, err = _signal(proc, signal.SIGINT)
    assert code == 130 and "Traceback" not in err, err
    assert len([ln for ln in _lines(err) if not ln.startswith("INFO")]) == 1, err
    assert "interrupted" in err and list(tmp_path.iterdir()) == []


def test_interrupted_evaluation_is_one_line(tmp_path):
    """Ctrl-C in `python -m sim.evaluate` printed a 48-line KeyboardInterrupt traceback."""
    out = tmp_path / "ev"
    proc = _start(["sim.evaluate", "pliers", "--views", "8", "--out", str(out), "--quiet",
                   "--no-manipulate"])
    _wait_for(lambda: (out / "cache").is_dir() and list((out / "cache").iterdir()), proc)
    time.sleep(2.0)  # both captures (this process and the spawned one for B) under way
    code, err = _signal(proc, signal.SIGINT)
    assert code == 130 and "Traceback" not in err, err
    assert len(_lines(err)) == 1 and "interrupted" in err, err
    # the cache holds no folder under a real name without its stage.json
    for p in (out / "cache").iterdir():
        assert p.name.startswith(".") or (p / "stage.json").is_file(), p


_ORPHAN_SCRIPT = """
import os, sys, time
from artrecon import workers

def task(path):
    open(path, "w").write(str(os.getpid()))
    time.sleep(120)

if __name__ == "__main__":
    pool = workers.pool(1)
    pool.submit(task, sys.argv[1])
    while not os.path.exists(sys.argv[1]):
        time.sleep(0.05)
    os.kill(os.getpid(), 9)  # killed outright: no code of the parent runs
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is dead (its parent, init here, reaps it)
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split()[2] == "Z")


@pytest.mark.skipif(sys.platform != "linux", reason="the parent-death signal is Linux's")
def test_a_killed_parents_worker_dies_with_it(tmp_path):
    """A parent killed with SIGKILL (a timeout, a scheduler) takes its pool's worker with it,
    instead of leaving it to run its task for minutes as an orphan."""
    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN_SCRIPT)
    pid_file = tmp_path / "worker.pid"
    proc = subprocess.run([sys.executable, str(script), str(pid_file)], cwd=REPO, timeout=120)
    assert proc.returncode == -signal.SIGKILL
    worker = int(pid_file.read_text())
    t0 = time.monotonic()
    while _alive(worker) and time.monotonic() - t0 < 10.0:
        time.sleep(0.05)
    assert not _alive(worker), f"worker {worker} outlived its killed parent"


_STOPPED_SCRIPT = """
import os, sys, time
from tqdm import tqdm
from artrecon import workers

def task(path):
    bar = tqdm(total=1, disable=True)  # a capture's bar, silenced as in --quiet
    open(path, "w").write(str(os.getpid()))
    time.sleep(120)

if __name__ == "__main__":
    pool = workers.pool(1)
    pool.submit(task, sys.argv[1])
    while not os.path.exists(sys.argv[1]):
        time.sleep(0.05)
    workers.stop(pool)  # as on Ctrl-C
    print("interrupted", file=sys.stderr)
"""


def test_a_stopped_worker_leaves_no_semaphore_behind(tmp_path):
    """A worker killed by workers.stop after its first progress bar: the parent's exit printed
    the resource tracker's "leaked semaphore objects" warning after the one "interrupted" line
    (tqdm's bar lock is a multiprocessing semaphore unless the worker has its own)."""
    script = tmp_path / "stopped.py"
    script.write_text(_STOPPED_SCRIPT)
    proc = subprocess.run([sys.executable, str(script), str(tmp_path / "worker.pid")], cwd=REPO,
                          timeout=120, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert _lines(proc.stderr) == ["interrupted"], proc.stderr
