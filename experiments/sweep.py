"""A ``-m`` sweep's parent: every job checked before any starts, and a signal that ends the whole tree.

:class:`SweepGuard` is a Hydra callback (registered in ``conf/config.yaml``). When a sweep starts it composes
every job's config and refuses the sweep, before any job runs, if a job sets a key its experiment never reads
(:func:`experiments.schemas.check_overrides`): the message names the key and the experiment.

While the sweep runs, SIGTERM, SIGINT and SIGHUP to the parent stop every job: the parent sends SIGTERM to its
child processes (the joblib/loky workers, submitit's local jobs; on Slurm it cancels the sweep's jobs with
``scancel``), whose running job marks itself failed and ends its own background workers
(:mod:`experiments.run`); after at most :data:`GRACE_S` seconds every process of the tree still alive gets
SIGKILL. Then every job that did not complete is marked failed in its ``status.json`` (a job that never started
gets a folder with its overrides and that status), the sweep report is written (:mod:`experiments.reports.sweep_report`), and
the parent dies by the signal it got.
"""

from __future__ import annotations

import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from experiments.reports.sweep_report import update_sweep_report
from experiments.runs.status import read_status, write_status

log = logging.getLogger("experiments")

#: environment variable naming the sweep parent's process id (a job in another process is a sweep worker)
SWEEP_PARENT = "HBNI_PYRO_SWEEP_PARENT"
#: seconds the parent waits for its jobs to mark themselves failed and exit before it kills what is left
GRACE_S = 20.0
SIGNALS = ("SIGTERM", "SIGINT", "SIGHUP")


def sweep_jobs(config: DictConfig) -> list[list[str]]:
    """The overrides of every job of the sweep ``config`` (the parent's config), in job order."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    overrides = OverridesParser.create().parse_overrides(list(config.hydra.overrides.task))
    return [list(job) for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]


def check_sweep(config: DictConfig, jobs: list[list[str]]) -> None:
    """Raise ``ValueError`` naming the key, the experiment and the job if a job sets a key its experiment never
    reads."""
    from hydra.core.global_hydra import GlobalHydra

    from experiments.schemas import check_overrides, typed_settings

    loader = GlobalHydra.instance().config_loader()
    for num, job in enumerate(jobs):
        try:
            settings = typed_settings(loader.load_sweep_config(config, list(job)))
        except ValueError:  # a job whose config fails its types fails as it starts, and the report lists it
            continue
        try:
            check_overrides(settings, job)
        except ValueError as exc:
            raise ValueError(f"{exc} (job {num}: {' '.join(job)})") from None


def in_sweep_worker() -> bool:
    """Whether this process runs a job for a sweep parent in another process (joblib, submitit, Slurm)."""
    parent = os.environ.get(SWEEP_PARENT)
    return parent is not None and parent != str(os.getpid())


def _start_time(pid: int) -> str | None:
    """The start time of process ``pid`` (``/proc/<pid>/stat``), ``None`` when it is gone or a zombie."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()
    return None if fields[0] in ("Z", "X") else fields[19]


def children(pid: int) -> list[int]:
    """The live child processes of ``pid`` (Linux ``/proc``)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            pass
    return [c for c in dict.fromkeys(out) if _start_time(c) is not None]


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid``."""
    out: list[int] = []
    todo = children(pid)
    while todo:
        child = todo.pop()
        if child not in out:
            out.append(child)
            todo += children(child)
    return out


def _ignores_sigterm(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    ignored = next((line.split()[1] for line in status.splitlines() if line.startswith("SigIgn:")), "0")
    return bool(int(ignored, 16) >> (signal.SIGTERM - 1) & 1)


class SweepGuard(Callback):
    """Hydra callback: check every job of a sweep before any starts, and stop the whole sweep on a signal."""

    def __init__(self) -> None:
        self._config: DictConfig | None = None
        self._jobs: list[list[str]] = []
        self._previous: dict[int, Any] = {}

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        jobs = sweep_jobs(config)
        try:
            check_sweep(config, jobs)
        except ValueError as exc:
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            print(f"config error: {exc}", file=sys.stderr)
            sys.exit(2)
        self._config, self._jobs = config, jobs
        os.environ[SWEEP_PARENT] = str(os.getpid())
        for name in SIGNALS:
            signum = getattr(signal, name)
            self._previous[signum] = signal.signal(signum, self._stop)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        os.environ.pop(SWEEP_PARENT, None)

    def _stop(self, signum: int, frame: object) -> None:
        """End every job, mark the unfinished ones failed, write the report, then die by ``signum``."""
        for name in SIGNALS:
            signal.signal(getattr(signal, name), signal.SIG_IGN)
        name = signal.Signals(signum).name
        assert self._config is not None
        sweep_dir = Path(str(self._config.hydra.sweep.dir))
        print(f"sweep stopped by {name}: ending its jobs (at most {GRACE_S:.0f} s)", file=sys.stderr)
        seen = {pid: _start_time(pid) for pid in descendants(os.getpid())}
        for pid in children(os.getpid()):
            _kill(pid, seen.get(pid), signal.SIGTERM)
        self._cancel_slurm_jobs(sweep_dir)
        deadline = time.monotonic() + GRACE_S
        while time.monotonic() < deadline:
            for pid in children(os.getpid()):  # a worker started since
                if pid not in seen:
                    seen[pid] = _start_time(pid)
                    _kill(pid, seen[pid], signal.SIGTERM)
            seen.update({pid: _start_time(pid) for pid in descendants(os.getpid()) if pid not in seen})
            waiting = [p for p, t in seen.items() if t is not None and _start_time(p) == t and not _ignores_sigterm(p)]
            if not waiting:
                break
            time.sleep(0.1)
        seen.update({pid: _start_time(pid) for pid in descendants(os.getpid()) if pid not in seen})
        for pid, started in seen.items():
            _kill(pid, started, signal.SIGKILL)
        self._mark_failed(sweep_dir, name)
        if sweep_dir.is_dir():
            update_sweep_report(sweep_dir)
        logging.shutdown()
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    def _cancel_slurm_jobs(self, sweep_dir: Path) -> None:
        """``scancel`` the sweep's Slurm jobs (submitit names its job folders by job id); Slurm sends them SIGTERM."""
        assert self._config is not None
        if not str(self._config.hydra.launcher.get("_target_", "")).endswith("SlurmLauncher"):
            return
        folder = Path(str(self._config.hydra.launcher.submitit_folder).replace("%j", ""))
        ids = sorted({p.name.split("_")[0] for p in folder.glob("*") if p.is_dir() and p.name[:1].isdigit()})
        if ids and shutil.which("scancel"):
            subprocess.run(["scancel", *ids], check=False, timeout=60)

    def _mark_failed(self, sweep_dir: Path, signal_name: str) -> None:
        """Mark every job that did not complete failed; a job that never started gets a folder with its overrides."""
        subdir = OmegaConf.to_container(self._config.hydra.sweep, resolve=False).get("subdir")  # type: ignore[union-attr]
        numbered = subdir == "${hydra.job.num}"
        folders = {int(p.name): p for p in sweep_dir.glob("*") if p.is_dir() and p.name.isdigit()}
        for num, job in enumerate(self._jobs):
            folder = folders.pop(num, sweep_dir / str(num) if numbered else None)
            if folder is None:
                continue
            try:
                status = read_status(folder)
            except ValueError:
                status = None
            if status is not None and status["status"] != "running":
                continue
            overrides = folder / ".hydra" / "overrides.yaml"
            if not overrides.is_file():
                overrides.parent.mkdir(parents=True, exist_ok=True)
                overrides.write_text(yaml.safe_dump(list(job)))
            started = status is not None
            error = (
                f"stopped by {signal_name}: the sweep was stopped"
                if started
                else f"not started: the sweep was stopped by {signal_name}"
            )
            write_status(folder, "failed", error=error)


def _kill(pid: int, started: str | None, signum: int) -> None:
    """Send ``signum`` to ``pid`` if it is still the process that started at ``started``."""
    if started is None or _start_time(pid) != started:
        return
    try:
        os.kill(pid, signum)
    except (ProcessLookupError, PermissionError):
        pass
