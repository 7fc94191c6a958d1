"""The single Hydra entry point: ``python -m experiments.run experiment=<name> [key=value ...]``.

Each ``conf/experiment/<name>.yaml`` names its study function in ``entry`` (a dotted path
to ``fn(cfg, run_dir) -> dict``). The function writes its figures and models into
``run_dir`` (Hydra's output directory) and returns the metrics, which are written to
``run_dir / "metrics.json"``.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import get_method
from omegaconf import DictConfig

from experiments.common import write_json


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> dict:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    metrics = get_method(cfg.entry)(cfg, run_dir)
    write_json(run_dir / "metrics.json", metrics)
    return metrics


if __name__ == "__main__":
    main()
