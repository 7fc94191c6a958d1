"""The single Hydra entry point: ``python -m experiments.run experiment=<name> [key=value ...]``.

Each ``conf/experiment/<name>.yaml`` names its study function in ``entry`` (a dotted path
to ``fn(settings, run_dir) -> dict``). Before the study starts, the composed config becomes the experiment's typed
settings, once (:func:`experiments.schemas.build_settings`): a wrong type, range or key fails here, naming the key.
The study and everything below it read that object, never the config. The function writes its figures and models into ``run_dir``
(Hydra's output directory) and returns the metrics, which are written to ``run_dir /
"metrics.json"``; a study that writes no ``report.md`` gets a summary one (:mod:`experiments.reports.run_report`).
``run_dir / "status.json"`` says whether the run is running, completed or failed (with the error);
:func:`experiments.load_run` refuses a run that did not complete.

Before Hydra writes anything, :class:`experiments.guard.RunGuard` checks the config and claims the run folder: a
config that fails its check, a folder a live run holds, or one that holds an earlier run (unless
``run.overwrite=true``) prints one line and exits with status 2, leaving no trace (:mod:`experiments.runs.claim`).
An error raised inside the run prints one line too, exit status 1; its traceback goes to ``run.log``
(``HYDRA_FULL_ERROR=1`` prints it).

SIGINT, SIGTERM and SIGHUP (Ctrl-C, ``kill``, ``timeout``, Slurm's time limit, a closed terminal) end a run within
seconds wherever they land, from the command's first instruction on: the run is marked failed, its background
workers end, and the process dies by the signal (:mod:`experiments.runs.signals`). A job of a ``-m`` sweep that runs
in a worker process (joblib, submitit) ends that process the same way, so that it takes no further job; the sweep's
parent stops the whole sweep on a signal (:mod:`experiments.sweep`). In a sweep, a job whose config fails its
check is marked failed instead, and the sweep's report lists it with its error.
"""

from __future__ import annotations

if __name__ == "__main__":  # `python -m experiments.run`: signals end the command from here on, imports included
    from experiments.runs import signals

    signals.install()

import logging  # noqa: E402
import os  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import hydra  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402
from hydra.types import RunMode  # noqa: E402
from hydra.utils import get_method  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

from experiments.reports.run_report import write_run_report  # noqa: E402
from experiments.runs import processes, signals  # noqa: E402
from experiments.runs.claim import FolderTaken, claim, release_all  # noqa: E402
from experiments.runs.outputs import write_json  # noqa: E402
from experiments.runs.status import write_status  # noqa: E402
from experiments.schemas import CONF, build_settings, check_overrides, register  # noqa: E402
from experiments.sweep import in_sweep_parent  # noqa: E402

log = logging.getLogger("experiments")
register()

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
    signals.install()
    if any(arg in HELP_FLAGS for arg in sys.argv[1:]):
        print(help_text())
        return
    try:
        run()
    except signals.Stopped as stop:  # stopped before the run's own code started
        signals.die(stop.signum, str(stop))
    finally:  # a sweep whose job failed ends here without Hydra's end-of-sweep callbacks: its folder's claim too
        release_all()


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def run(cfg: DictConfig) -> dict:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    sweep_job = HydraConfig.get().mode == RunMode.MULTIRUN
    tic = time.perf_counter()
    try:
        if sweep_job:
            _claim_job(run_dir)
        try:
            settings = build_settings(cfg)
            check_overrides(settings, list(HydraConfig.get().overrides.task))
        except (TypeError, ValueError) as exc:  # in a sweep (a single run's config was checked before it started)
            write_status(run_dir, "failed", error=f"{type(exc).__name__}: {exc}")  # the sweep's report lists the job
            log.error("experiment %s: config error: %s", cfg.name, exc)
            raise
        try:
            log.info("experiment %s (seed %s): writing to %s", settings.name, settings.seed, run_dir)
            write_status(run_dir, "running")
            metrics = get_method(settings.entry)(settings, run_dir)
            write_json(run_dir / "metrics.json", metrics)
            write_run_report(run_dir, settings, metrics)
            with signals.deferred():
                write_status(run_dir, "completed")
                signals.finish()
        except BaseException as exc:
            _failed(exc, settings.name, run_dir, time.perf_counter() - tic, sweep_job)
            raise
    finally:
        release_all()
    log.info("experiment %s done in %.1f s; outputs in %s", settings.name, time.perf_counter() - tic, run_dir)
    return metrics


def _claim_job(run_dir: Path) -> None:
    """A sweep job's hold on its own folder (the sweep's parent checked it before any job started); in a worker
    process, signals from now on mark the job failed. A folder that a live run holds fails the job."""
    worker = not in_sweep_parent()  # a job run in the parent's process leaves signals to the parent's handler
    if worker:
        signals.install()
    try:
        with signals.deferred():
            claim(run_dir, check_previous=False)
            if worker:
                signals.begin(lambda error: write_status(run_dir, "failed", error=error))
    except FolderTaken as exc:
        log.error("run folder error: %s", exc)
        raise


def _failed(exc: BaseException, name: str, run_dir: Path, seconds: float, sweep_job: bool) -> None:
    """Mark the run failed and say so. A stop ends the process by its signal (its workers first); a single run's
    own error prints one line on stderr (the traceback goes to ``run.log``) and exits with status 1; a sweep job's
    error returns to the sweep, which lists it in its report."""
    signum = signals.acknowledge()
    stop = f"stopped by {signal.Signals(signum).name}" if signum else ""
    why = f"Stopped: {stop}" if signum else f"{type(exc).__name__}: {exc}"
    write_status(run_dir, "failed", error=why)
    log.error("experiment %s failed after %.1f s: %s", name, seconds, why)
    if signum:
        processes.end_descendants()
        logging.shutdown()
        signals.die(
            signum, None if sweep_job else f"experiment {name} {stop} after {seconds:.1f} s; marked failed in {run_dir}"
        )
    if sweep_job or os.environ.get("HYDRA_FULL_ERROR") == "1":
        return
    _log_traceback(exc)
    logging.shutdown()
    release_all()
    lines = why.splitlines() or [why]
    where = f"traceback{' and whole message' if len(lines) > 1 else ''} in {run_dir / 'run.log'}; HYDRA_FULL_ERROR=1 prints it"
    print(f"error: experiment {name} failed after {seconds:.1f} s: {lines[0]} ({where})", file=sys.stderr)
    sys.exit(1)


def _log_traceback(exc: BaseException) -> None:
    """Write ``exc``'s traceback to the run's log file only (not to the console)."""
    record = log.makeRecord(
        log.name, logging.ERROR, __file__, 0, "traceback:", None, (type(exc), exc, exc.__traceback__)
    )
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


if __name__ == "__main__":
    main()
