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


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_thread_counts(bad):
    with pytest.raises(ValueError, match="threads: expected an int >= 1 or None"):
        with torch_threads(bad):
            pass
