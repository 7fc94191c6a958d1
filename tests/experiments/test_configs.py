"""Every experiment config composes with Hydra's compose API and names an importable entry point."""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import get_method

CONF = Path(__file__).resolve().parents[2] / "conf"
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def test_there_are_experiments():
    assert "hbni_toy" in EXPERIMENTS


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_config_composes(name):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[f"experiment={name}"], return_hydra_config=True)
    assert cfg.name == name
    assert callable(get_method(cfg.entry))
    assert cfg.hydra.launcher._target_.endswith("JoblibLauncher")
