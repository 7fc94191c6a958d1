"""Thread control restores torch's, NumPy BLAS's and OpenCV's settings, also after an exception, rejects bad counts,
and one setting covers a whole run."""

import importlib

import cv2
import pytest
import torch
from threadpoolctl import ThreadpoolController, threadpool_info

from hbni_infra.threads import set_threads, single_thread, torch_threads, worker_threads


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_threads_are_restored():
    before, blas, cv = torch.get_num_threads(), _blas_threads(), cv2.getNumThreads()
    assert blas  # NumPy's BLAS is found
    with single_thread():
        assert torch.get_num_threads() == 1 and set(_blas_threads()) == {1} and cv2.getNumThreads() == 1
    assert torch.get_num_threads() == before and _blas_threads() == blas and cv2.getNumThreads() == cv
    with torch_threads(None):
        assert torch.get_num_threads() == before and cv2.getNumThreads() == cv
    with pytest.raises(RuntimeError), torch_threads(1):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == before and cv2.getNumThreads() == cv


@pytest.mark.parametrize(
    "bad, error", [(0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)]
)
def test_bad_thread_counts(bad, error):
    with pytest.raises(error, match="threads: expected an int"):
        with torch_threads(bad):
            pass


def test_a_whole_runs_setting_covers_torch_blas_opencv_and_compiled_loops(monkeypatch):
    before, blas, cv = torch.get_num_threads(), _blas_threads(), cv2.getNumThreads()
    monkeypatch.setattr(
        importlib.import_module("hbni_infra.threads"), "_workers", None
    )  # the module, not hbni_infra.threads()
    with ThreadpoolController().limit(limits=blas[0], user_api="blas"):  # restores NumPy's BLAS afterwards
        try:
            set_threads(1)
            assert torch.get_num_threads() == 1 and set(_blas_threads()) == {1} and worker_threads() == 1
            assert cv2.getNumThreads() == 1
        finally:
            torch.set_num_threads(before)
            cv2.setNumThreads(cv)


def test_a_count_given_as_a_function_is_asked_at_each_use():
    """Compiled loops ask the function each time (the cores background work leaves may change inside the block);
    torch takes its value on entry; a bad value is refused when asked."""
    threads = importlib.import_module("hbni_infra.threads").threads
    before = torch.get_num_threads()
    free = [1]
    with threads(lambda: free[0]):
        assert worker_threads() == 1 and torch.get_num_threads() == 1
        free[0] = 2
        assert worker_threads() == 2 and torch.get_num_threads() == 1
        free[0] = 0
        with pytest.raises(ValueError, match=r"threads\(\): expected an int >= 1"):
            worker_threads()
    assert torch.get_num_threads() == before
    with pytest.raises(ValueError, match="threads: expected an int"), threads(lambda: 0):
        pass


def test_a_nested_block_of_the_same_count_changes_nothing(monkeypatch):
    """A frame classified alone passes through several blocks of one count: only the outermost sets and restores."""
    real, calls = torch.set_num_threads, []

    def counted(n: int) -> None:
        calls.append(n)
        real(n)

    with torch_threads(1):
        monkeypatch.setattr(torch, "set_num_threads", counted)
        with torch_threads(1), torch_threads(None):
            assert torch.get_num_threads() == 1
        assert calls == []
        with torch_threads(2):  # another count still changes it, and restores it
            assert torch.get_num_threads() == 2
        assert calls == [2, 1] and torch.get_num_threads() == 1
