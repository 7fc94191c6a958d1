"""Smoke run of the hbni_toy experiment through the real Hydra entry point."""

import json
import subprocess
import sys

from hbni_pyro import HBNIPosterior


def test_hbni_toy_runs_end_to_end(tmp_path, repo_root):
    cmd = [
        sys.executable,
        "-m",
        "experiments.run",
        "experiment=hbni_toy",
        f"hydra.run.dir={tmp_path}",
        "hbni.fit.num_chains=4",
        "hbni.fit.num_samples=100",
        "hbni.fit.warmup_steps=100",
        "progress=false",
    ]
    subprocess.run(cmd, cwd=repo_root, check=True, capture_output=True)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert set(metrics["summary"]) == {"theta[0]", "theta[1]", "theta[2]", "kappa", "gamma"}
    assert metrics["theta_true"] == [1.0, 6.0, 20.0]
    for png in ("theta_posterior.png", "hyperparameters.png"):
        assert (tmp_path / png).stat().st_size > 10_000
    post = HBNIPosterior.load(tmp_path / "posterior.safetensors")
    assert post.samples["theta"].shape == (4, 100, 3)
    assert (tmp_path / ".hydra" / "config.yaml").is_file()
