"""The dpomdp_benchmarks experiment: a smoke run through the real Hydra entry point (tiny settings), its
config (every optimum cited, published horizon-2 optima equal exhaustive search on the shipped files),
and config errors raised before any work."""

import json
import math
from pathlib import Path

import pytest
from experiment_runs import run_experiment
from omegaconf import OmegaConf

from decpomdp import JointController
from decpomdp.dpomdp import TabularDecPOSMDP
from decpomdp.dpomdp.exhaustive import exhaustive_optimum
from experiments.schemas import build_settings, compose_config
from experiments.studies.dpomdp_benchmarks import build_rows, fraction_of_optimum

REPO = Path(__file__).resolve().parents[2]
CONFIG = OmegaConf.load(REPO / "conf" / "experiment" / "dpomdp_benchmarks.yaml")


def _rows(row: str | None = None, key: str | None = None, value=None) -> list:
    """``build_rows`` on the experiment's settings, built from its composed config with ``study.rows.<row>.<key>``
    set to ``value`` (as a run builds them: the schema checks every row, then the rows' planners are built)."""
    plain = OmegaConf.to_container(compose_config(["experiment=dpomdp_benchmarks"]), resolve=False)
    if row is not None:
        plain["study"]["rows"][row][key] = value
    settings = build_settings(OmegaConf.create(plain))
    return build_rows(settings.study, settings.planner)


SMOKE_ROWS = ["dectiger_h2", "broadcast_h4", "firefighting_h2", "firefighting_h4_monte_carlo", "broadcast_inf"]


def test_dpomdp_benchmarks_smoke(tmp_path):
    run_experiment(
        [
            "experiment=dpomdp_benchmarks",
            f"hydra.run.dir={tmp_path}",
            "progress=false",
            "study.caps.iterations=2",
            "study.caps.samples=20",
            "study.caps.restarts=1",
            "study.random_controllers=10",
            f"study.only=[{','.join(SMOKE_ROWS)}]",
        ],
        REPO,
    )
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    rows = metrics["rows"]
    assert set(rows) == set(SMOKE_ROWS) <= set(CONFIG.study.rows)
    for name, row in rows.items():
        assert row["controllers_per_run"] == 2 * 20 and row["paper_budget"]["samples"] == 20
        ctrl = JointController.load(tmp_path / "controllers" / f"{name}.safetensors")
        assert ctrl.num_controllers == 1
        solved = row["solve"]
        assert JointController.load(tmp_path / "controllers" / f"{name}_solve.safetensors").num_controllers == 1
        assert solved["gap"] >= 0 and solved["value"] <= solved["bound"] + 1e-9 and solved["settings"]["restarts"] == 1
        assert solved["proven"] == (solved["bound"] - solved["value"] <= 1e-6 * abs(solved["value"]))
        if row["optimum"] is not None and row["horizon"] != "inf":  # infinite rows: best known, not proven optima
            assert row["gdice_value"] <= row["optimum"] + 1e-9  # no controller beats the optimum
            assert row["meets_95"] == (row["fraction_of_optimum"] >= 0.95)
            assert solved["value"] <= row["optimum"] + 1e-9 <= solved["bound"] + 2e-9  # the bound holds the optimum
            assert solved["meets_99"] == (solved["fraction_of_optimum"] >= 0.99)
    assert rows["dectiger_h2"]["horizon"] == 2 and rows["broadcast_inf"]["horizon"] == "inf"
    assert rows["firefighting_h2"]["optimum_source"].startswith("exhaustive search over all 4096")
    assert rows["firefighting_h4_monte_carlo"]["evaluator"] == "monte_carlo"
    assert metrics["rows_scored"] == sum(r["meets_95"] is not None for r in rows.values())
    assert (tmp_path / "dpomdp_benchmarks.png").stat().st_size > 20_000
    assert (tmp_path / "table.md").read_text().count("\n") == len(rows) + 2


def test_every_optimum_cites_its_source_and_horizon_2_optima_fit_the_shipped_files():
    checked = 0
    for name, row in CONFIG.study.rows.items():
        assert row.source, name
        if row.optimum is not None and row.horizon == 2:
            env = TabularDecPOSMDP.from_problem(row.problem, gamma=float(row.gamma), horizon=2)
            assert exhaustive_optimum(env, 2)[0] == pytest.approx(row.optimum, abs=1e-6), name
            checked += 1
    assert checked == 11


def test_fraction_of_optimum():
    assert fraction_of_optimum(9.0, 10.0, 0.0) == pytest.approx(0.9)  # V / V* for a positive optimum
    assert fraction_of_optimum(-4.2, -4.0, -90.0) == pytest.approx(0.95)  # shortfall 0.2 of |V*| = 4
    assert fraction_of_optimum(-0.5, 0.0, -10.0) == pytest.approx(0.95)  # V* = 0: over the random shortfall
    assert fraction_of_optimum(0.0, 0.0, 0.0) == 1.0


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("problem", "nope", "study.rows.dectiger_h2.problem: expected one of"),
        ("gamma", 1.5, "study.rows.dectiger_h2.gamma"),
        ("horizon", 2.5, "study.rows.dectiger_h2.horizon"),
        ("evaluator", "guess", "study.rows.dectiger_h2.evaluator"),
        ("colour", "red", r"study.rows.dectiger_h2.colour: Key 'colour' not in 'BenchmarkRow'"),
        ("gdice", {"num_nodes": 3, "layer_width": 5}, "study.rows.dectiger_h2.gdice"),
    ],
)
def test_config_errors_name_the_key_before_any_work(key, value, message):
    with pytest.raises(ValueError, match=message):
        _rows("dectiger_h2", key, value)


def test_infinite_rows_need_a_discount():
    with pytest.raises(ValueError, match="study.rows.recycling_inf.horizon: null"):
        _rows("recycling_inf", "gamma", 1.0)
    assert all(math.isfinite(config.ce_alpha) for _, config, _ in _rows())


@pytest.mark.parametrize(
    "override, message",
    [
        ("study.rows.dectiger_h2.problem=nope", "study.rows.dectiger_h2.problem: expected one of"),
        ("study.rows.dectiger_h2.evaluator=guess", "study.rows.dectiger_h2.evaluator: expected one of"),
        ("study.rows.recycling_inf.gamma=1.0", r"study.rows.recycling_inf.horizon: null \(infinite\) needs gamma < 1"),
        ("study.rows.dectiger_h2.restarts=0", "study.rows.dectiger_h2.restarts: expected an int >= 1"),
        ("study.paper_budget.ce_samples=0", "study.paper_budget.ce_samples: expected an int >= 1"),
        ("study.rows.recycling_inf.evaluator=monte_carlo", "study.rows.recycling_inf.evaluator: monte_carlo rollouts"),
        ("study.only=[dectiger_h2,nope]", r"study.only: unknown rows \['nope'\]"),
        ("+study.solve.guess=1", r"study.solve: unknown settings \['guess'\]"),
    ],
)
def test_composed_config_fails_naming_the_key(override, message):
    """The typed schema rejects a bad row when the config is composed and checked, before the run starts."""
    from experiments.schemas import build_settings, compose_config

    cfg = compose_config(["experiment=dpomdp_benchmarks", override])
    with pytest.raises(ValueError, match=message):
        build_settings(cfg)
