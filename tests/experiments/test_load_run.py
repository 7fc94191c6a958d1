"""The hbni_toy experiment through the real Hydra entry point, and load_run on its run directory: a round trip, and
clear errors for missing pieces."""

import json
import shutil

import pytest
import torch
from experiment_runs import run_experiment

from experiments import load_run
from hbni_pyro import HBNIPosterior


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory, repo_root):
    run_dir = tmp_path_factory.mktemp("toy")
    args = [
        "experiment=hbni_toy",
        f"hydra.run.dir={run_dir}",
        "hbni.fit.num_chains=2",
        "hbni.fit.num_samples=50",
        "hbni.fit.warmup_steps=50",
        "progress=false",
    ]
    run_experiment(args, repo_root)
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
    run = load_run(copy)  # lazy: the metrics and the other artefacts stay readable
    assert run.metrics["theta_true"] == [1.0, 6.0, 20.0] and isinstance(run.posterior_near_perfect, HBNIPosterior)
    with pytest.raises(FileNotFoundError, match="artefact 'posterior' .* is missing"):
        run.posterior
    (copy / "posterior.safetensors").write_bytes(b"garbage")
    with pytest.raises(
        ValueError,
        match=r"artefact 'posterior' \(HBNIPosterior\) in .*posterior.safetensors.* cannot "
        "be read: .*is not a readable model file",
    ):
        load_run(copy).posterior
    (copy / "artifacts.json").unlink()
    with pytest.raises(AttributeError, match="recorded no artefacts"):
        load_run(copy).posterior
    (copy / "artifacts.json").write_text("{not json")
    with pytest.raises(ValueError, match="corrupt manifest"):
        load_run(copy)


def test_the_toy_study_writes_its_summary_figures_and_posterior(toy_run):
    metrics = json.loads((toy_run / "metrics.json").read_text())
    assert set(metrics["summary"]) == {"theta[0]", "theta[1]", "theta[2]", "kappa", "gamma"}
    assert metrics["theta_true"] == [1.0, 6.0, 20.0]
    for png in ("theta_posterior.png", "hyperparameters.png"):
        assert (toy_run / png).stat().st_size > 10_000
    assert HBNIPosterior.load(toy_run / "posterior.safetensors").samples["theta"].shape == (2, 50, 3)
    assert (toy_run / ".hydra" / "config.yaml").is_file()


def test_a_run_says_where_it_wrote_and_fills_its_log(toy_run):
    assert json.loads((toy_run / "status.json").read_text()) == {"status": "completed"}
    log = (toy_run / "run.log").read_text()
    assert f"writing to {toy_run}" in log and f"outputs in {toy_run}" in log


def test_a_failed_run_is_marked_and_refused(tmp_path, repo_root):
    args = [
        "experiment=hbni_toy",
        f"hydra.run.dir={tmp_path}",
        "entry=experiments.studies.hbni_toy.no_such_study",
        "progress=false",
    ]  # fails once started
    proc = run_experiment(args, repo_root, check=False)
    assert proc.returncode != 0 and "no_such_study" in proc.stderr
    status = json.loads((tmp_path / "status.json").read_text())
    assert status["status"] == "failed" and "no_such_study" in status["error"]
    with pytest.raises(ValueError, match="(?s)failed .*no_such_study.*pass allow_incomplete=True"):
        load_run(tmp_path)
    run = load_run(tmp_path, allow_incomplete=True)
    assert run.metrics == {} and run.cfg.entry == "experiments.studies.hbni_toy.no_such_study"


def test_an_unfinished_run_is_refused(toy_run, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(toy_run, copy)
    (copy / "metrics.json").unlink()
    with pytest.raises(ValueError, match="did not finish"):
        load_run(copy)
    (copy / "status.json").write_text('{"status": "running"}')
    with pytest.raises(ValueError, match="did not finish"):
        load_run(copy)
    (copy / "status.json").write_text('{"status": "sleeping"}')
    with pytest.raises(ValueError, match="expected a status in"):
        load_run(copy)


def _without_timings(obj):
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if "seconds" not in k}
    return [_without_timings(v) for v in obj] if isinstance(obj, list) else obj


def test_the_same_seed_gives_byte_identical_metrics(toy_run, tmp_path, repo_root):
    args = [
        "experiment=hbni_toy",
        f"hydra.run.dir={tmp_path}",
        "hbni.fit.num_chains=2",
        "hbni.fit.num_samples=50",
        "hbni.fit.warmup_steps=50",
        "progress=false",
    ]
    run_experiment(args, repo_root)
    first, second = (json.loads((d / "metrics.json").read_text()) for d in (toy_run, tmp_path))
    assert json.dumps(_without_timings(first)) == json.dumps(_without_timings(second))
