"""Thread control restores torch's setting, also after an exception, and rejects bad counts."""

import pytest
import torch

from infra.threads import single_thread, torch_threads


def test_threads_are_restored():
    before = torch.get_num_threads()
    with single_thread():
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError), torch_threads(1):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == before


@pytest.mark.parametrize(
    "bad, error", [(0, ValueError), (-1, ValueError), (1.5, TypeError), (True, TypeError), ("2", TypeError)]
)
def test_bad_thread_counts(bad, error):
    with pytest.raises(error, match="threads: expected an int"):
        with torch_threads(bad):
            pass
