"""load_run: a round trip through a real run directory, and clear errors for missing pieces."""

import shutil
import subprocess
import sys

import pytest
import torch

from experiments import load_run
from hbni_pyro import HBNIPosterior


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory, repo_root):
    run_dir = tmp_path_factory.mktemp("toy")
    cmd = [
        sys.executable, "-m", "experiments.run", "experiment=hbni_toy", f"hydra.run.dir={run_dir}",
        "hbni.fit.num_chains=2", "hbni.fit.num_samples=50", "hbni.fit.warmup_steps=50", "progress=false",
    ]
    subprocess.run(cmd, cwd=repo_root, check=True, capture_output=True)
    return run_dir


def test_load_run_round_trip(toy_run):
    run = load_run(toy_run)
    assert run.cfg.name == "hbni_toy" and run.cfg.hbni.fit.num_samples == 50
    assert run.metrics["theta_true"] == [1.0, 6.0, 20.0]
    assert isinstance(run.posterior, HBNIPosterior)
    direct = HBNIPosterior.load(toy_run / "posterior.safetensors")
    assert torch.equal(run.posterior.samples["theta"], direct.samples["theta"])
    assert set(run.posterior.summary()) >= {"kappa", "gamma"}
    assert "posterior_near_perfect" in dir(run)
    with pytest.raises(AttributeError, match="no artefact or attribute 'classifier'"):
        run.classifier


def test_missing_run_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such run directory"):
        load_run(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match="not a Hydra run directory"):
        load_run(tmp_path)


def test_missing_and_corrupt_artefacts(toy_run, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(toy_run, copy)
    (copy / "posterior.safetensors").unlink()
    with pytest.raises(FileNotFoundError, match="artefact 'posterior' .* is missing"):
        load_run(copy)
    (copy / "posterior.safetensors").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="is not a readable model file"):
        load_run(copy)
    (copy / "artifacts.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt manifest"):
        load_run(copy)
