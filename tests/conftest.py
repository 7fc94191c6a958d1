"""Shared pytest setup: the repository root, a single-threaded torch for small tensor programs, and the ``slow``
marker on every test that starts an experiment process."""

from __future__ import annotations

import functools
import inspect
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import torch
from filelock import FileLock

from experiment_runs import run_experiment
from mission_tiny import TINY_BANKS, TINY_MISSION

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config: pytest.Config) -> None:
    """In the main process of a run with xdist workers, before they start: compile the numba kernels into their
    on-disk cache, in two processes side by side (``tests/compile_kernels.py``), so that the workers load them
    instead of each compiling them at once on a fresh machine. A run without workers compiles each kernel once
    anyway, where a test first needs it. A part that fails is reported; the tests that need it then fail."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return
    script = REPO_ROOT / "tests" / "compile_kernels.py"
    parts = ("package_delivery", "others")
    jobs = [subprocess.Popen([sys.executable, "-P", str(script), part], cwd=REPO_ROOT) for part in parts]
    for part, job in zip(parts, jobs, strict=True):
        if job.wait():
            print(f"tests/compile_kernels.py {part}: exit status {job.returncode}", file=sys.stderr)


def pytest_sessionstart(session: pytest.Session) -> None:
    """In the main process of a run with xdist workers, before they start: make the shared tiny main-job run
    (:func:`tiny_mission_run`) in a background thread, so that it is ready, or nearly, when the first test that
    reads it starts, instead of one worker making it while every other one that needs it waits on its lock. Returns
    once the thread holds the lock (a worker that needs the run meanwhile waits for it, as it would for a worker)."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", 0):
        return
    locked = threading.Event()

    def build() -> None:
        try:
            build_tiny_mission(config._tmp_path_factory.getbasetemp(), locked)
        except Exception:  # the tests that need the run make it again and fail with its error
            locked.set()

    thread = threading.Thread(target=build, name="tiny-mission", daemon=True)
    thread.start()
    locked.wait()
    config.stash[_TINY_BUILD] = thread


def pytest_sessionfinish(session: pytest.Session) -> None:
    """Wait for the background tiny run (:func:`pytest_sessionstart`) if it is still going (a run that selected
    no test needing it)."""
    thread = session.config.stash.get(_TINY_BUILD, None)
    if thread is not None:
        thread.join()


_TINY_BUILD = pytest.StashKey[threading.Thread]()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark ``slow`` every test that runs ``experiments.run`` (in its body, a module-level helper it calls or a
    fixture it uses): ``pytest -m "not slow"`` then skips the whole-experiment runs. The modules with a slow test go
    first (those whose slow tests all read the shared tiny run after the others, as it is made meanwhile), each
    module's tests together in their collected order: the workers then end on short tests instead of one of them
    running a whole experiment while the others have nothing left."""
    for item in items:
        if _starts_an_experiment(item):
            item.add_marker(pytest.mark.slow)
    rank: dict[str, int] = {}  # per module file, the lowest rank of its tests: a module's tests stay together
    for item in items:
        rank[item.path] = min(rank.get(item.path, 2), _rank(item))
    items.sort(key=lambda item: rank[item.path])


def _rank(item: pytest.Item) -> int:
    """0: slow and not reading the tiny run, 1: slow and reading it, 2: not slow."""
    if item.get_closest_marker("slow") is None:
        return 2
    return int("tiny_mission_run" in getattr(item, "fixturenames", ()))


def _starts_an_experiment(item: pytest.Item) -> bool:
    function = getattr(item, "function", None)
    if function is None:
        return False
    module = inspect.getmodule(function)
    parts = [function, *(getattr(module, name, None) for name in function.__code__.co_names)]
    info = getattr(item, "_fixtureinfo", None)
    for defs in info.name2fixturedefs.values() if info else ():
        for fixture in defs:
            parts += [fixture.func, *(getattr(module, n, None) for n in fixture.func.__code__.co_names)]
    return any(_runs_an_experiment(part) for part in parts if inspect.isfunction(part))


@functools.cache
def _runs_an_experiment(function: Callable) -> bool:
    """Whether ``function``'s source starts ``python -m experiments.run``, itself or through
    :func:`experiment_runs.run_experiment` (read once per function: the items of a
    parametrized test and the tests sharing a fixture ask again)."""
    try:
        source = inspect.getsource(function)
    except OSError:
        return False
    return "run_experiment(" in source or ("experiments.run" in source and "sys.executable" in source)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture
def signals_delivered() -> Iterator[None]:
    """The stop signals (SIGINT, SIGTERM, SIGHUP) handled by default in the processes the test starts, also when
    pytest itself was started ignoring them (a shell's background job ignores SIGINT, ``nohup`` SIGHUP): an ignored
    signal stays ignored across ``exec``, and a run leaves a signal it was started ignoring ignored."""
    ignored = [s for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) if signal.getsignal(s) == signal.SIG_IGN]
    for signum in ignored:
        signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL)
    yield
    for signum in ignored:
        signal.signal(signum, signal.SIG_IGN)


@pytest.fixture(scope="session")
def tiny_mission_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One finished main-job run with the tiny settings, shared by every test (and xdist worker) that only reads
    it: ``<root>/outputs/mission/2026-01-01_00-00-00``, made under ``HBNI_PYRO_ROOT=<root>`` (with workers, by the
    main process in the background from the session's start: :func:`pytest_sessionstart`)."""
    base = tmp_path_factory.getbasetemp()
    return build_tiny_mission(base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base)


def build_tiny_mission(shared: Path, locked: threading.Event | None = None) -> Path:
    """The tiny run under ``shared`` (the workers' common folder), made unless there, on one torch thread as a
    worker's runs are (the main process's thread count would give another classifier, and the tests that rerun the
    run's settings another bank); ``locked`` is set once this call holds the run's file lock (a caller that waits
    for it knows every later call waits for the run)."""
    root = shared / "tiny-mission"
    run_dir = root / "outputs" / "mission" / "2026-01-01_00-00-00"
    with FileLock(str(shared / "tiny-mission.lock")):
        if locked is not None:
            locked.set()
        if not (run_dir / "metrics.json").is_file():
            run_experiment(
                [
                    "experiment=mission",
                    *TINY_MISSION,
                    TINY_BANKS,
                    f"hydra.run.dir={run_dir}",
                    "mission.bank.workers=1",
                ],  # the bank built in the background
                REPO_ROOT,
                env={**os.environ, "HBNI_PYRO_ROOT": str(root), "OMP_NUM_THREADS": "1"},  # as in a worker
            )
    return run_dir


# Small tensor programs on a busy machine: torch's intra-op threads wait on each other far longer than they work
# (an experiment's tiny fit took 3x the CPU time on two threads beside the other workers). Under xdist every core
# already runs a worker, so each worker, and every experiment process it starts, runs torch on one thread; tests
# about thread counts set them explicitly.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"
    torch.set_num_threads(1)
else:
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
