"""The one cache: entries keyed by everything that produced them, code included; refusal of a file written
for another key; one builder per entry across processes (the lock), and a dead builder's lock taken over."""

import os
import subprocess
import sys
import threading
import time

import pytest
import torch

from hbni_infra.cache import FileLock, cached, entry_path, source_identity, store_entry


def test_cache_refuses_a_file_written_for_other_inputs(tmp_path):
    calls = []

    def compute():
        calls.append(1)
        return {"x": torch.arange(3.0)}

    a, path, hit = cached(tmp_path, "k", {"seed": 0, "frames": 4}, compute)
    b, _, hit_b = cached(tmp_path, "k", {"seed": 0, "frames": 4}, compute)
    assert not hit and hit_b and len(calls) == 1 and torch.equal(a["x"], b["x"])
    _, other, _ = cached(tmp_path, "k", {"seed": 1, "frames": 4}, compute)
    assert other != path and len(calls) == 2  # other inputs, another file
    other.rename(path)  # a file whose stored key does not match its name's inputs
    with pytest.raises(ValueError, match="seed was 1 there, is 0 here"):
        cached(tmp_path, "k", {"seed": 0, "frames": 4}, compute)
    assert cached(None, "k", {}, compute)[1] is None
    assert not list(tmp_path.glob("*.lock"))  # every lock released


def test_source_identity_follows_the_code(tmp_path, monkeypatch):
    package = tmp_path / "cachedpkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "render.py").write_text("SCALE = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = source_identity("cachedpkg")
    assert source_identity("cachedpkg") == before and source_identity("cachedpkg.render") != before
    (package / "render.py").write_text("SCALE = 2\n")
    assert source_identity("cachedpkg") != before


def test_a_live_lock_makes_others_wait_for_the_entry(tmp_path):
    key = {"seed": 0}
    path = entry_path(tmp_path, "k", key)
    builder = FileLock(path)
    assert builder.acquire() and not FileLock(path).acquire()

    def finish():  # the builder writes the entry where the waiting run looks, then lets go of its lock
        time.sleep(1.5)
        store_entry(path, key, {"x": torch.ones(2)})
        builder.release()

    thread = threading.Thread(target=finish)
    thread.start()
    tensors, _, hit = cached(tmp_path, "k", key, lambda: pytest.fail("the waiting run must not compute"))
    thread.join()
    assert hit and torch.equal(tensors["x"], torch.ones(2)) and not builder.path.exists()


def test_a_lock_left_by_a_dead_process_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    path = entry_path(tmp_path, "k", {})
    lock = FileLock(path)
    lock.path.parent.mkdir(parents=True, exist_ok=True)
    lock.path.write_text(f"{os.uname().nodename} {dead.stdout.strip()}")
    with pytest.warns(RuntimeWarning, match="breaking a stale cache lock .process .* of this host no longer runs"):
        tensors, _, hit = cached(tmp_path, "k", {}, lambda: {"x": torch.zeros(1)})
    assert not hit and torch.equal(tensors["x"], torch.zeros(1)) and not lock.path.exists()
