"""filtering_error and macro_observation: configs compose, tiny runs go through the real entry point,
and a -m sweep over hbni.filter.mode runs both jobs through the joblib launcher."""

from __future__ import annotations

import json

import pytest
import torch
import yaml
from experiment_runs import run_experiment

from experiments.schemas import compose_config, compose_settings
from experiments.studies.filtering_error import first_crossing, run as run_filtering, wilson_bounds
from hbni_pyro import HBNIPosterior, MacroObservationModel

TINY_FIT = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=40", "hbni.fit.warmup_steps=40", "progress=false"]
TINY_FILTERING = [
    "study.num_trials=40",
    "study.num_training_sets=2",
    "study.training_sizes=[15,30]",
    "study.max_len=8",
    "study.filter_draws=30",
    *TINY_FIT,
]


@pytest.mark.parametrize("name", ["filtering_error", "macro_observation"])
def test_configs_compose_with_the_hbni_group(name):
    cfg = compose_config([f"experiment={name}", "hbni.filter.mode=plugin"])
    assert cfg.name == name and cfg.entry == f"experiments.studies.{name}.run"
    assert cfg.hbni.filter.mode == "plugin" and cfg.hbni.fit.method == "mh"
    assert list(cfg.study.true_theta) == [1.0, 6.0, 20.0]
    if name == "filtering_error":
        assert list(cfg.study.training_sizes) == [15, 30, 60, 150]
        assert cfg.study.num_trials == 2000 and cfg.study.num_training_sets >= 20 and cfg.study.max_len == 50


def test_wilson_bounds_and_crossings():
    lo, hi = wilson_bounds(torch.tensor([0, 10, 2000]), 2000)
    # closed form at k = 0: upper = z^2 / (n + z^2)
    assert float(lo[0]) == 0 and float(hi[0]) == pytest.approx(1.959964**2 / (2000 + 1.959964**2), rel=1e-6)
    assert float(lo[1]) < 10 / 2000 < float(hi[1]) and float(hi[2]) == 1
    err = torch.tensor([0.3, 0.04, 0.06, 0.008, 0.0], dtype=torch.float64)
    assert first_crossing(err, 0.05) == 2 and first_crossing(err, 0.01) == 4 and first_crossing(err, 0.001) == 5
    assert first_crossing(err, -1) is None


def test_filtering_error_smoke(tmp_path, repo_root):
    run_experiment(["experiment=filtering_error", f"hydra.run.dir={tmp_path}", *TINY_FILTERING], repo_root)
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["N"] == list(range(1, 9)) and m["settings"]["hbni_filter_mode"] == "plugin"
    for size in ("15", "30"):
        for method in ("voting", "max_of_mean", "ssbf", "calibrated", "hbni", "hbni_oracle"):
            e = m["error"][size][method]
            assert len(e["error"]) == 8 and all(lo <= x <= hi for lo, x, hi in zip(e["lo"], e["error"], e["hi"]))
            assert set(m["crossing_n"][size][method]) == {"0.05", "0.01", "0.005"}
        assert "crossing_ratio_hbni_over_baseline" in m["comparison"][size]["ssbf"]
        assert "crossing_ratio_hbni_over_baseline" in m["comparison"][size]["calibrated"]
    assert set(m["acceptance"]) == {
        "train15_hbni_at_or_below_every_baseline_at_every_n",
        "train15_intervals_separated_wherever_baseline_above_1pct",
        "train15_1pct_n_at_most_half_of_each_baseline",
    }
    # baselines do not depend on training: the same trials give the same curves at every size
    assert m["error"]["15"]["ssbf"] == m["error"]["30"]["ssbf"]
    for png in ("error_curves.png", "crossing_vs_training_size.png"):
        assert (tmp_path / png).stat().st_size > 10_000
    assert HBNIPosterior.load(tmp_path / "posterior_train15_set0.safetensors").num_chains == 2


def test_macro_observation_smoke(tmp_path, repo_root):
    run_experiment(
        [
            "experiment=macro_observation",
            f"hydra.run.dir={tmp_path}",
            "study.num_streams=40",
            "study.max_frames=10",
            "study.filter_draws=30",
            *TINY_FIT,
        ],
        repo_root,
    )
    m = json.loads((tmp_path / "metrics.json").read_text())
    for name in ("hbni", "calibrated", "ssbf"):
        for source in ("true_theta", "posterior_predictive"):
            d = m["processes"][name][source]
            assert all(sum(row) == pytest.approx(1, abs=1e-12) for row in d["confusion"])
            assert all(len(row) == 10 and sum(row) == pytest.approx(1, abs=1e-12) for row in d["frames_pmf"])
            model = MacroObservationModel.load(tmp_path / f"macro_{name}_{source}.safetensors")
            torch.testing.assert_close(model.confusion, torch.tensor(d["confusion"], dtype=torch.float64))
    assert (tmp_path / "macro_observation.png").stat().st_size > 10_000


def test_sweep_over_filter_mode_runs_both_jobs_with_joblib(tmp_path, repo_root):
    run_experiment(
        [
            "-m",
            "experiment=filtering_error",
            "hbni.filter.mode=marginal,plugin",
            f"hydra.sweep.dir={tmp_path}",
            *TINY_FILTERING,
            "study.training_sizes=[15]",
        ],
        repo_root,
    )
    modes = {
        json.loads((tmp_path / str(k) / "metrics.json").read_text())["settings"]["hbni_filter_mode"] for k in (0, 1)
    }
    assert modes == {"marginal", "plugin"}
    launcher = yaml.safe_load((tmp_path / "multirun.yaml").read_text())["hydra"]["launcher"]
    assert launcher["_target_"].endswith("JoblibLauncher") and launcher["n_jobs"] == 2


def test_filtering_error_is_a_function_of_the_seed(tmp_path):
    def metrics(seed, sub):
        settings = compose_settings(["experiment=filtering_error", f"seed={seed}", *TINY_FILTERING])
        (tmp_path / sub).mkdir()
        return run_filtering(settings, tmp_path / sub)

    a, b, c = metrics(3, "a"), metrics(3, "b"), metrics(4, "c")
    for size in (15, 30):
        for method in ("ssbf", "hbni"):
            assert torch.equal(a["error"][size][method]["wrong"], b["error"][size][method]["wrong"])
    assert any(not torch.equal(a["error"][15][m]["wrong"], c["error"][15][m]["wrong"]) for m in ("ssbf", "hbni"))
