"""The single Hydra entry point: ``python -m experiments.run experiment=<name> [key=value ...]``.

Each ``conf/experiment/<name>.yaml`` names its study function in ``entry`` (a dotted path
to ``fn(settings, run_dir) -> dict``). Before the study starts, the composed config becomes the experiment's typed
settings, once (:func:`experiments.schemas.build_settings`): a wrong type, range or key fails here, naming the key.
The study and everything below it read that object, never the config. The function writes its figures and models into ``run_dir``
(Hydra's output directory) and returns the metrics, which are written to ``run_dir /
"metrics.json"``. ``run_dir / "status.json"`` says whether the run is running, completed or
failed (with the error); :func:`experiments.load_run` refuses a run that did not complete. SIGTERM and
SIGHUP (``kill``, ``timeout``, Slurm's time limit, ``docker stop``, a closed terminal) stop a run as
Ctrl-C does: it is marked failed and its background workers end. A job of a ``-m`` sweep that runs in a worker
process (joblib, submitit) then ends that process by the same signal, so that it takes no further job; the
sweep's parent stops the whole sweep on a signal (:mod:`experiments.sweep`). A key the experiment never reads
is refused before the run starts, naming the key and the experiment (:func:`experiments.schemas.check_overrides`).

A config that fails its check prints one line (``HYDRA_FULL_ERROR=1`` for the traceback) and leaves no
run folder behind: the run never started. In a sweep (``-m``) such a job is marked failed instead, and the
sweep's report lists it with its error.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from hydra.utils import get_method
from omegaconf import DictConfig, OmegaConf

from experiments.runs.outputs import write_json
from experiments.runs.status import write_status
from experiments.schemas import CONF, build_settings, check_overrides, register
from experiments.sweep import in_sweep_worker

log = logging.getLogger("experiments")
register()


class Stopped(BaseException):
    """The run was stopped by a signal (SIGTERM or SIGHUP); like ``KeyboardInterrupt``, not an ``Exception``."""

    def __init__(self, signum: int) -> None:
        super().__init__(f"stopped by {signal.Signals(signum).name}")
        self.signum = signum


def _stop(signum: int, frame: object) -> None:
    raise Stopped(signum)


def _config_error(run_dir: Path, exc: Exception) -> None:
    """Report a config that fails its check in one line, remove the run folder Hydra made for it, and exit 2."""
    if os.environ.get("HYDRA_FULL_ERROR") == "1":
        raise exc
    logging.shutdown()  # Hydra's log file lives in the run folder
    if run_dir.is_dir() and not any(
        p.name not in (".hydra", "run.log", f"{HydraConfig.get().job.name}.log") for p in run_dir.iterdir()
    ):
        shutil.rmtree(run_dir, ignore_errors=True)
    print(f"config error: {exc}", file=sys.stderr)
    sys.exit(2)


HELP_FLAGS = ("--help", "-h")
"""Flags that print the experiments' list (:func:`help_text`) instead of running one."""


def help_text() -> str:
    """The ``hydra.help.template`` of ``conf/config.yaml``: the command line and the experiments, one per line.

    :func:`main` prints it without composing any config: Hydra's own ``--help`` first lists every config group,
    which copies the whole config store for each group (seconds), although the template shows none of them."""
    config = OmegaConf.load(CONF / "config.yaml")
    return config.hydra.help.template


def main() -> None:
    """The console entry point (``hbni-pyro``, ``python -m experiments.run``): ``--help`` or ``-h`` prints
    :func:`help_text`; anything else is a run (or a ``-m`` sweep) of :func:`run`."""
    if any(arg in HELP_FLAGS for arg in sys.argv[1:]):
        print(help_text())
        return
    run()


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def run(cfg: DictConfig) -> dict:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    tic = time.perf_counter()
    try:
        settings = build_settings(cfg)
        check_overrides(settings, list(HydraConfig.get().overrides.task))
    except (TypeError, ValueError) as exc:
        if HydraConfig.get().mode != RunMode.MULTIRUN:
            _config_error(run_dir, exc)
        write_status(run_dir, "failed", error=f"{type(exc).__name__}: {exc}")  # a sweep's report lists the job
        log.error("experiment %s: config error: %s", cfg.name, exc)
        raise
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGTERM", "SIGHUP"):
            previous[getattr(signal, name)] = signal.signal(getattr(signal, name), _stop)
    try:
        log.info("experiment %s (seed %s): writing to %s", settings.name, settings.seed, run_dir)
        write_status(run_dir, "running")
        metrics = get_method(settings.entry)(settings, run_dir)
        write_json(run_dir / "metrics.json", metrics)
    except BaseException as exc:
        write_status(run_dir, "failed", error=f"{type(exc).__name__}: {exc}")
        log.error(
            "experiment %s failed after %.1f s: %s: %s",
            settings.name,
            time.perf_counter() - tic,
            type(exc).__name__,
            exc,
        )
        signum = exc.signum if isinstance(exc, Stopped) else signal.SIGINT if isinstance(exc, KeyboardInterrupt) else 0
        if signum and in_sweep_worker():  # a sweep's worker process ends with its job: it takes no further job
            logging.shutdown()
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        raise
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    write_status(run_dir, "completed")
    log.info("experiment %s done in %.1f s; outputs in %s", settings.name, time.perf_counter() - tic, run_dir)
    return metrics


if __name__ == "__main__":
    main()
