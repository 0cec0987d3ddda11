"""artrecon.workers.side_by_side: the two configurations' work in two threads."""

import threading

import numpy as np
import pytest

from artrecon import workers


def test_side_by_side_returns_both_results_in_order_from_two_threads():
    names = []

    def task(value):
        def run():
            names.append(threading.current_thread().name)
            return np.full(3, value)
        return run

    a, b = workers.side_by_side(task(1), task(2))
    assert a.tolist() == [1, 1, 1] and b.tolist() == [2, 2, 2]
    assert len(set(names)) == 2  # B ran in its own thread


def test_side_by_side_raises_either_tasks_error():
    def fail():
        raise ValueError("B failed")

    with pytest.raises(ValueError, match="B failed"):
        workers.side_by_side(lambda: 1, fail)
    with pytest.raises(KeyError):
        workers.side_by_side(lambda: {}["a"], lambda: 2)


def test_single_threaded_restores_the_thread_counts():
    import cv2
    from threadpoolctl import threadpool_info

    before = cv2.getNumThreads(), [p["num_threads"] for p in threadpool_info()
                                   if p["user_api"] == "blas"]
    with workers.single_threaded():
        assert cv2.getNumThreads() == 1
        assert all(p["num_threads"] == 1 for p in threadpool_info() if p["user_api"] == "blas")
    assert (cv2.getNumThreads(), [p["num_threads"] for p in threadpool_info()
                                  if p["user_api"] == "blas"]) == before
