"""A single run's checks before Hydra writes anything: its config, then its folder.

:class:`RunGuard` is a Hydra callback (registered in ``conf/config.yaml``); Hydra calls it once the config is
composed and before it creates the run folder, opens ``run.log`` there or saves ``.hydra/``:

1. The config: the experiment's typed settings are built and the overrides checked
   (:func:`experiments.schemas.build_settings`, :func:`experiments.schemas.check_overrides`). A config that fails
   prints one line, ``config error: ...``, and the command exits with status 2: no folder is made.
2. The folder: the run claims it (:func:`experiments.runs.claim.claim`). A folder that a live run holds, or that holds
   an earlier run or sweep while ``run.overwrite`` is false, prints one line, ``run folder error: ...``, and the
   command exits with status 2, having changed nothing there. From the claim on, a signal marks the run failed
   (:mod:`experiments.runs.signals`).

``HYDRA_FULL_ERROR=1`` raises the error instead, with its traceback. A ``-m`` sweep's parent checks its jobs and
claims the sweep's folder the same way (:class:`experiments.sweep.SweepGuard`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from experiments.runs import signals
from experiments.runs.claim import FolderTaken, claim
from experiments.runs.status import write_status
from experiments.schemas import build_settings, check_overrides
from experiments.sweep import refuse


class RunGuard(Callback):
    """Hydra callback: check a single run's config, then claim its folder, before Hydra writes into it."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        try:
            settings = build_settings(config)
            check_overrides(settings, list(config.hydra.overrides.task))
        except (TypeError, ValueError) as exc:
            refuse("config error", exc)
        run_dir = Path(str(config.hydra.run.dir)).absolute()
        try:
            with signals.deferred():
                claim(run_dir, overwrite=settings.run.overwrite)
                signals.begin(lambda error: write_status(run_dir, "failed", error=error))
        except (FolderTaken, ValueError) as exc:
            refuse("run folder error", exc)
