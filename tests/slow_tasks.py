"""Tasks for tests that run them in a spawned worker process (artrecon.workers.pool): a module
of their own, importing nothing heavy, since the worker imports the task's module to unpickle
it (a test module importing mujoco before sim fails there: the EGL set-up of sim/__init__)."""

from __future__ import annotations

import os
import time
from pathlib import Path


def slow_configuration_b(*args) -> None:
    """Configuration B's stage, standing in for a long SfM and dense stereo: it takes 20 s and
    then leaves a mark (at ``$ARTRECON_TEST_B_MARK``)."""
    time.sleep(20.0)
    Path(os.environ["ARTRECON_TEST_B_MARK"]).write_text("B ran to its end")


def rasteriser_threads() -> str | None:
    """The worker's ``LP_NUM_THREADS`` (Mesa llvmpipe's rasteriser threads), None if unset."""
    return os.environ.get("LP_NUM_THREADS")


def busy(seconds: float) -> float:
    """Keep one core busy for ``seconds`` of this process's CPU; returns the CPU it used."""
    start = time.process_time()
    while time.process_time() - start < seconds:
        sum(i * i for i in range(10000))
    return time.process_time() - start
