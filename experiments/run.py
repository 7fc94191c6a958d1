"""The single Hydra entry point: ``python -m experiments.run experiment=<name> [key=value ...]``.

Each ``conf/experiment/<name>.yaml`` names its study function in ``entry`` (a dotted path
to ``fn(cfg, run_dir) -> dict``). Before the study starts, the composed config is checked
against the experiment's typed schema (:mod:`experiments.schemas`): a wrong type, range or key
fails here, naming the key. The function writes its figures and models into ``run_dir``
(Hydra's output directory) and returns the metrics, which are written to ``run_dir /
"metrics.json"``. ``run_dir / "status.json"`` says whether the run is running, completed or
failed (with the error); :func:`experiments.load_run` refuses a run that did not complete.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_method
from omegaconf import DictConfig

from experiments.common import write_json
from experiments.schemas import check_config, register
from experiments.status import write_status

log = logging.getLogger("experiments")
register()


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> dict:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    tic = time.perf_counter()
    try:
        check_config(cfg)
        log.info("experiment %s (seed %s): writing to %s", cfg.name, cfg.seed, run_dir)
        write_status(run_dir, "running")
        metrics = get_method(cfg.entry)(cfg, run_dir)
        write_json(run_dir / "metrics.json", metrics)
    except BaseException as exc:
        write_status(run_dir, "failed", error=f"{type(exc).__name__}: {exc}")
        log.error("experiment %s failed after %.1f s: %s: %s", cfg.name, time.perf_counter() - tic, type(exc).__name__, exc)
        raise
    write_status(run_dir, "completed")
    log.info("experiment %s done in %.1f s; outputs in %s", cfg.name, time.perf_counter() - tic, run_dir)
    return metrics


if __name__ == "__main__":
    main()
