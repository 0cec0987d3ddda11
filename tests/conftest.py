"""Fixtures shared across test modules.

The rendered hinge fixture (:mod:`render_fixture`) and its two reconstructions are session-wide:
defined here once, they are rendered and reconstructed once per run for every module that uses
them (defined in each module, pytest treated them as distinct fixtures and rebuilt them per
module: about 7 minutes of CI), by whichever xdist worker asks first (:func:`_once`).

The suite runs on two pytest-xdist workers (``-n 2 --dist loadscope`` in pyproject.toml), a
module at a time per worker, with one exception (:func:`pytest_xdist_make_scheduler`): the
end-to-end gates of :mod:`test_gates` and :mod:`test_author_gates` are split into one unit per
scene, so that the nine scene evaluations spread over both workers instead of one worker running
all of them while the other runs out of work (CI at 369e9c3: 60 min, most of it that one module).
"""

import fcntl
import os
import re
import shutil

import pytest
import render_fixture

#: Modules whose tests are parametrised by scene first (``test_x[scene-...]``, ``test_x[scene]``)
#: and evaluate each scene once per process: each scene is its own unit of work.
PER_SCENE_MODULES = ("tests/test_gates.py", "tests/test_author_gates.py")

#: Units handed out first, in this order: the longest (measured serially at 30faea6, seconds:
#: the scene evaluations 200-780 each, test_photo_route 590, test_configuration 130,
#: test_faults 120, test_sweep 105, test_dense 77, test_manipulate_model 67), so that the short
#: modules fill the gaps at the end instead of a long one starting last. A scene name stands for
#: its per-scene unit, a file name for its module. The rest follow by test count.
LONGEST_FIRST = ("cabinet_door_only", "truck", "test_photo_route.py", "scissors", "chest",
                 "cabinet", "drawer", "scraper_truck", "mm_cabinet", "truck_panda", "pliers",
                 "pliers_panda", "barrett_hand", "test_configuration.py", "test_faults.py",
                 "test_sweep.py", "test_dense.py", "test_manipulate_model.py", "test_bad_input.py",
                 "test_confidence.py", "test_capture.py", "test_reachability.py")


def scene_scope(nodeid: str) -> str:
    """The xdist work unit of a test: its module, or module::scene for the per-scene modules."""
    module, _, rest = nodeid.partition("::")
    m = re.search(r"\[([A-Za-z0-9_]+)[-\]]", rest)
    if module in PER_SCENE_MODULES and m:
        return f"{module}::{m.group(1)}"
    return nodeid.rsplit("::", 1)[0] if "::" in rest else module


def _unit_rank(scope: str) -> int:
    name = scope.rpartition("::")[2] if "::" in scope else scope.rpartition("/")[2]
    return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    """Items grouped by work unit (:func:`scene_scope`), the long scene evaluations first, then
    the other units by test count, each unit's tests in their own order. Every worker collects
    the same order, and the scheduler hands the units out in it."""
    units: dict[str, list] = {}
    for item in items:
        units.setdefault(scene_scope(item.nodeid), []).append(item)
    order = sorted(units, key=lambda u: (_unit_rank(u), -len(units[u])))
    items[:] = [item for u in order for item in units[u]]


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Load-scope scheduling over the units of :func:`scene_scope`, in collection order."""
    if config.getoption("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class SceneScopeScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return scene_scope(nodeid)

    config.option.loadscopereorder = False  # keep the order of pytest_collection_modifyitems
    return SceneScopeScheduling(config, log)


def _once(tmp_path_factory, name: str, build, load):
    """``build(folder)`` once per test run, ``load(folder)`` in the other xdist workers.

    A session fixture is per process: each of the suite's two workers rendered the hinge
    fixture and ran its two reconstructions (about 75 s of CI's CPU, twice). The first worker
    to ask builds into a folder both share, under an exclusive lock, and marks it done; the
    other waits on the lock and reads the result. A build that fails leaves no mark, so the
    next worker to ask builds again (and fails with its own error). Without xdist: built."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return build(tmp_path_factory.mktemp(name))
    folder = tmp_path_factory.getbasetemp().parent / f"shared-{name}"
    with open(f"{folder}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if (folder / ".done").is_file():
            return load(folder)
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        result = build(folder)
        (folder / ".done").touch()
        return result


@pytest.fixture(scope="session")
def rendered(tmp_path_factory):
    """Configuration A and B of the hinge fixture, rendered once per run."""
    def sets(root, render):
        return {c: render_fixture.render_set(root / c, c, render_fixture.TEST_VIEWS,
                                             render=render) for c in ("a", "b")}

    return _once(tmp_path_factory, "hinge", lambda root: sets(root, True),
                 lambda root: sets(root, False))


def _reconstruction(tmp_path_factory, rendered, name: str, **kwargs):
    from artrecon import reconstruct
    from artrecon.model import ArticulatedModel

    def build(root):
        out = root / name
        return reconstruct(rendered["a"].folder, rendered["b"].folder, out_dir=out,
                           progress=False, **kwargs), out

    def load(root):
        return ArticulatedModel.load(root / name / "model.json"), root / name

    return _once(tmp_path_factory, f"run-{name}", build, load)


@pytest.fixture(scope="session")
def reconstruction_sfm(rendered, tmp_path_factory):
    """The whole run, cameras from the images alone (the method's default)."""
    return _reconstruction(tmp_path_factory, rendered, "sfm")


@pytest.fixture(scope="session")
def reconstruction_poses(rendered, tmp_path_factory):
    """The whole run with the cameras' known poses (fast path)."""
    return _reconstruction(tmp_path_factory, rendered, "poses", poses=True)
