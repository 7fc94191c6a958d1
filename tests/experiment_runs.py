"""Experiment runs for the tests: ``python -m experiments.run <args>``, each in its own process, started from an
interpreter that has already imported the project.

A fresh interpreter spends about 2.5 s importing torch, pyro, Hydra and the project before a run starts, and the
suite starts dozens of runs. :func:`run_experiment` forks each run instead from a server process (multiprocessing's
``forkserver``, one per test worker) that has imported :mod:`experiments.run` once: the run is still a separate
process with its own working directory, environment, standard streams, exit status and Hydra output folder, and
it runs the console entry point :func:`experiments.run.main` on ``sys.argv`` as ``python -m`` would.

What the server read when it imported the project stays as it was then: the numba cache directory and the thread
counts. A run whose environment changes such a setting (:data:`READ_AT_IMPORT`) starts a fresh interpreter, as do
the tests of start-up itself (the console script, signals, the import graph), which call ``subprocess`` directly.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
import re
import subprocess
import sys
import tempfile
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path

READ_AT_IMPORT = ("NUMBA_", "OMP_", "MKL_", "OPENBLAS_", "TORCH", "PYTHON", "XDG_CACHE_HOME")
"""Prefixes of environment variables read when the project is imported: a run that changes one starts afresh."""

PROMISED = ("status.json", "metrics.json", "report.md")
"""The files ``--help`` says every run writes."""

TESTS = Path(__file__).resolve().parent
"""The tests' directory, which pytest puts on ``sys.path``: a run does not see it (its folders would shadow the
packages of the same names)."""

_server = multiprocessing.get_context("forkserver")
_server.set_forkserver_preload(["experiments.run", __name__])


def run_experiment(
    args: Sequence[str | os.PathLike],
    cwd: str | os.PathLike,
    *,
    env: Mapping[str, str] | None = None,
    check: bool = True,
    timeout: float | None = None,
) -> subprocess.CompletedProcess[str]:
    """``python -m experiments.run *args`` in ``cwd`` with ``env`` (default: this process's), as
    ``subprocess.run(..., capture_output=True, text=True)`` would return it; ``check`` raises
    :class:`subprocess.CalledProcessError` on a non-zero exit, ``timeout`` (seconds) kills the run and raises
    :class:`subprocess.TimeoutExpired`.

    A single run that completes must do what ``--help`` says every run does (:func:`check_promised_outputs`)."""
    args = [str(a) for a in args]
    env = dict(os.environ if env is None else env)
    command = [sys.executable, "-m", "experiments.run", *args]
    if _changes_import_settings(env):
        done = subprocess.run(command, cwd=cwd, env=env, check=check, timeout=timeout, capture_output=True, text=True)
        check_promised_outputs(args, cwd, done)
        return done
    with tempfile.TemporaryDirectory(prefix="experiment-run-") as streams:
        out, err = Path(streams, "stdout"), Path(streams, "stderr")
        process = _server.Process(target=_run_main, args=(args, str(cwd), env, str(out), str(err)), name="experiment")
        process.start()
        process.join(timeout)
        if process.exitcode is None:
            process.kill()
            process.join()
            raise subprocess.TimeoutExpired(command, timeout, out.read_text(), err.read_text())
        done = subprocess.CompletedProcess(command, process.exitcode, out.read_text(), err.read_text())
    if check:
        done.check_returncode()
    check_promised_outputs(args, cwd, done)
    return done


def check_promised_outputs(args: Sequence[str], cwd: str | os.PathLike, done: subprocess.CompletedProcess[str]) -> None:
    """What ``--help`` promises of every run (:func:`experiments.run.help_text`), checked on a completed single run:
    it says where it wrote its outputs, and that folder holds the files of :data:`PROMISED`."""
    if done.returncode != 0 or "-m" in args or "--multirun" in args or {"-h", "--help"} & set(args):
        return
    said = re.findall(r"done in [0-9.]+ s; outputs in (.+)$", done.stdout, flags=re.MULTILINE)
    assert said, f"the run did not say where it wrote its outputs: {done.stdout[-2000:]}"
    folder = Path(cwd, said[-1])
    missing = [name for name in PROMISED if not (folder / name).is_file()]
    assert not missing, f"{folder} lacks {missing}, which --help says every run writes"


def _changes_import_settings(env: Mapping[str, str]) -> bool:
    """Whether ``env`` differs from this process's environment in a variable of :data:`READ_AT_IMPORT`."""
    keys = {k for k in (*env, *os.environ) if k.startswith(READ_AT_IMPORT)}
    return any(env.get(k) != os.environ.get(k) for k in keys)


def _run_main(args: list[str], cwd: str, env: dict[str, str], out: str, err: str) -> None:
    """In the forked process: take the run's directory, import path, environment and streams, run the entry point,
    then the exit handlers that a fresh interpreter runs when it ends (multiprocessing's child ends without them)."""
    os.chdir(cwd)
    sys.path[:] = [cwd, *(p for p in sys.path if p and not Path(p).resolve().is_relative_to(TESTS))]  # as `-m` sets it
    os.environ.clear()
    os.environ.update(env)
    for fd, path in ((1, out), (2, err)):
        handle = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(handle, fd)
        os.close(handle)
    import experiments.run

    sys.argv = [experiments.run.__file__, *args]
    try:
        experiments.run.main()
    finally:  # as the interpreter ends: threads (and their exit hooks: joblib's workers stop there), then atexit
        threading._shutdown()
        atexit._run_exitfuncs()
