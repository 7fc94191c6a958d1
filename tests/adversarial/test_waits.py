"""The waiting boundary: every call that used to loop or wait forever on a bad input ends, with an error naming the
argument or the file, or a warning naming the lock it breaks. Each call runs in a daemon thread joined with a
timeout, so a hang fails the test instead of the suite."""

from __future__ import annotations

import math
import os
import socket
import threading
import time
import warnings

import pytest
import torch

import hbni_infra.cache as cache
import hbni_pyro.distributions.sampling as sampling
from hbni_infra.cache import FileLock, cached, entry_path, store_entry, wait_for_entry
from hbni_pyro import HBNIPosterior, sample_dirichlet, sample_outputs
from hbni_pyro.distributions import gamma_variates, sample_gamma

LIMIT = 60.0  # seconds a call may take before it counts as a hang (each ends in well under a second)


def _ends(call):
    """``call()``'s result or exception, or a failure if it is still running after ``LIMIT`` seconds."""
    out: dict = {}

    def run():
        try:
            out["value"] = call()
        except BaseException as exc:  # noqa: BLE001 -- handed to the test
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(LIMIT)
    if thread.is_alive():
        pytest.fail(f"still running after {LIMIT:g} s: a hang")
    return out


def _refused(call, error: type, name: str) -> str:
    out = _ends(call)
    assert "error" in out, f"accepted, returned {out.get('value')!r:.80}"
    assert isinstance(out["error"], error), repr(out["error"])
    assert name in str(out["error"]), str(out["error"])
    return str(out["error"])


def _g() -> torch.Generator:
    return torch.Generator().manual_seed(0)


def _posterior(theta: torch.Tensor) -> HBNIPosterior:
    draws = theta.to(torch.float64).expand(1, 4, -1).clone()
    ones = torch.ones(1, 4, dtype=torch.float64)
    return HBNIPosterior({"theta": draws, "kappa": ones, "gamma": ones}, torch.full((3,), 1 / 3, dtype=torch.float64))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, -1.0, -2.0, -1e300])
def test_sample_outputs_refuses_a_theta_it_cannot_sample(bad):
    """The README quickstart's sampler looped forever on these (the gamma draw never accepted)."""
    theta = torch.tensor([bad, 6.0, 20.0])
    _refused(lambda: sample_outputs(theta, torch.tensor([0, 1]), _g()), ValueError, "theta")


def test_sample_outputs_ends_on_a_theta_between_minus_one_and_minus_two_thirds():
    """Valid Dirichlet concentrations in (0, 1/3] that the squeeze method alone never accepted."""
    out = _ends(lambda: sample_outputs(torch.tensor([-0.9, 1.0, 1.0]), torch.zeros(100, dtype=torch.long), _g()))
    assert "value" in out and torch.isfinite(out["value"]).all()


@pytest.mark.parametrize("bad", [math.nan, -1.0, 0.0])
def test_sample_dirichlet_refuses_what_it_cannot_sample(bad):
    _refused(lambda: sample_dirichlet(torch.tensor([bad, 1.0]), _g()), ValueError, "alpha")


@pytest.mark.parametrize("bad", [math.nan, math.inf, 0.5, 0.2])
def test_sample_gamma_refuses_shapes_below_one(bad):
    _refused(lambda: sample_gamma(torch.tensor([bad, 2.0], dtype=torch.float64), _g()), ValueError, "shape")


def test_gamma_variates_refuses_a_nan_shape():
    _refused(lambda: gamma_variates(torch.tensor([math.nan]), 1.0, _g()), ValueError, "shape")


@pytest.mark.parametrize("bad", [-2.0, math.nan, math.inf])
def test_a_posterior_with_an_impossible_theta_refuses_to_sample_instead_of_hanging(bad):
    """A posterior holding such a theta (loaded from an edited file, or built by hand) hung every sampler."""

    def draw():
        return _posterior(torch.tensor([bad, 6.0, 20.0])).sample_streams(0, 3, 2)

    _refused(draw, ValueError, "theta")


def test_the_rejection_loop_has_a_bound_and_a_message(monkeypatch):
    monkeypatch.setattr(sampling, "MAX_ROUNDS", 0)
    _refused(lambda: sample_gamma(torch.tensor([2.0], dtype=torch.float64), _g()), RuntimeError, "sample_gamma")


# the cache's lock ------------------------------------------------------------------------------------------------


def _lock_file(tmp_path, content: str, age: float = 0.0):
    path = entry_path(tmp_path, "k", {})
    lock = FileLock(path)
    lock.path.write_text(content)
    if age:
        past = time.time() - age
        os.utime(lock.path, (past, past))
    return path, lock


def _compute():
    return {"x": torch.ones(2)}


@pytest.mark.parametrize(
    "content, why",
    [
        ("", "empty or unreadable"),
        ("garbage", "empty or unreadable"),
        ("other-host 123", "untouched for"),
        (f"{socket.gethostname()} {os.getpid()}", "untouched for"),
    ],
    ids=["empty", "unreadable", "another host", "this host, live pid, no heartbeat"],
)
def test_a_stale_lock_is_broken_with_a_warning_naming_its_path(tmp_path, content, why):
    """Empty, unreadable, foreign or same-host locks untouched for longer than STALE_SECONDS: cached() waited on
    them forever, without a word."""
    _, lock = _lock_file(tmp_path, content, age=cache.STALE_SECONDS + 60)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = _ends(lambda: cached(tmp_path, "k", {}, _compute))
    assert "value" in out, out.get("error")
    tensors, _, hit = out["value"]
    assert not hit and torch.equal(tensors["x"], torch.ones(2)) and not lock.path.exists()
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert any(str(lock.path) in m and "stale" in m and why in m for m in messages), messages


@pytest.mark.parametrize(
    "content",
    ["", "other-host 123", f"{socket.gethostname()} {os.getpid()}"],
    ids=["empty, being written", "another host", "this host, live"],
)
def test_a_live_lock_is_waited_on_until_the_deadline_then_named(tmp_path, content):
    path, lock = _lock_file(tmp_path, content)
    message = _refused(lambda: cached(tmp_path, "k", {}, _compute, timeout=0.2), TimeoutError, str(lock.path))
    assert "delete the lock file" in message and lock.path.exists() and not path.exists()


def test_the_lock_names_its_holder_in_the_timeout(tmp_path):
    _, lock = _lock_file(tmp_path, "robot-7 4242")
    message = _refused(lambda: cached(tmp_path, "k", {}, _compute, timeout=0), TimeoutError, "robot-7")
    assert "4242" in message


@pytest.mark.parametrize("bad, error", [(math.nan, ValueError), (-1.0, ValueError), ("soon", TypeError)])
def test_a_bad_timeout_is_refused(tmp_path, bad, error):
    _refused(lambda: cached(tmp_path, "k", {}, _compute, timeout=bad), error, "timeout")
    lock = FileLock(entry_path(tmp_path, "j", {}))
    _refused(lambda: wait_for_entry(entry_path(tmp_path, "j", {}), {}, lock, "entry", bad), error, "timeout")


def test_the_holder_keeps_its_lock_fresh_while_it_builds(tmp_path, monkeypatch):
    """The heartbeat is what tells a live builder on another host from a dead one."""
    monkeypatch.setattr(cache, "HEARTBEAT_SECONDS", 0.01)
    lock = FileLock(entry_path(tmp_path, "k", {}))
    assert lock.acquire()
    try:
        past = time.time() - 1000
        os.utime(lock.path, (past, past))
        deadline = time.monotonic() + LIMIT
        while lock.path.stat().st_mtime < past + 500 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert lock.path.stat().st_mtime > past + 500 and lock.stale() is None
    finally:
        lock.release()
    assert not lock.path.exists()


def test_a_waiter_gets_the_entry_the_live_builder_writes(tmp_path):
    key = {"seed": 0}
    path = entry_path(tmp_path, "k", key)
    builder = FileLock(path)
    assert builder.acquire()

    def finish():
        time.sleep(0.3)
        store_entry(path, key, {"x": torch.zeros(3)})
        builder.release()

    threading.Thread(target=finish, daemon=True).start()
    out = _ends(lambda: cached(tmp_path, "k", key, lambda: pytest.fail("the waiter must not compute"), timeout=LIMIT))
    tensors, _, hit = out["value"]
    assert hit and torch.equal(tensors["x"], torch.zeros(3))


def test_a_wait_says_what_it_waits_for_and_what_bounds_it(tmp_path, caplog):
    """A wait on a live lock (up to STALE_SECONDS for a lock whose holder is gone) said nothing until it ended."""
    _, lock = _lock_file(tmp_path, "robot-7 4242")
    with caplog.at_level("WARNING", logger="hbni_infra.cache"):
        _refused(lambda: cached(tmp_path, "k", {}, _compute, timeout=0.3), TimeoutError, "robot-7")
    said = [r.getMessage() for r in caplog.records if r.name == "hbni_infra.cache"]
    assert len(said) == 1 and str(lock.path) in said[0] and "process 4242 on host 'robot-7'" in said[0], said
    assert "at most 0.3 s (timeout of hbni_infra.cache.cached" in said[0] and "STALE_SECONDS" in said[0]
