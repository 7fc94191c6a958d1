"""Sweep reports: swept keys as columns, the experiment's headline metrics, failed jobs with their error."""

import json

from experiment_runs import run_experiment

from experiments.reports.sweep_report import headline_values, multirun_report

FIT = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=30", "hbni.fit.warmup_steps=30", "progress=false"]


def test_a_sweep_with_a_failing_job_still_writes_its_report(tmp_path, repo_root):
    args = ["-m", "experiment=hbni_toy", "toy.per_class=2,0", f"hydra.sweep.dir={tmp_path}", *FIT]
    proc = run_experiment(args, repo_root, check=False)
    assert proc.returncode != 0  # the failing job fails the sweep ...
    report = (tmp_path / "report.md").read_text()  # ... and the report is there all the same
    header = next(line for line in report.splitlines() if line.startswith("| job"))
    assert "| toy.per_class |" in header and "summary.theta[0].mean" in header and "label_accuracy" in header
    rows = [line for line in report.splitlines() if line.startswith("| [")]
    assert rows[0].startswith("| [0](0/) | completed | 2 | ") and rows[1].startswith("| [1](1/) | failed | 0 |")
    assert (
        "## Failed jobs" in report
        and "job 1 (`toy.per_class=0`): ValueError: toy.per_class: expected an int >= 1" in report
    )
    assert "Every job: " in report and "`hbni.fit.num_chains=2`" in report
    theta = json.loads((tmp_path / "0" / "metrics.json").read_text())["summary"]["theta[0]"]["mean"]
    assert f"| {theta:.4g} |" in rows[0]


def test_headline_values_format_and_expand():
    metrics = {
        "gdice": {"value": 13.812, "stderr": 0.0412, "delivered_per_rollout": 9.0},
        "variants": {
            "hbni": {"value": 5.8, "stderr": 0.02, "wrong_rate": 0.022},
            "ssbf": {"value": 5.2, "stderr": 0.03},
        },
        "crossing": {"15": {"0.05": 3, "0.01": None}},
        "acc": [0.5, 0.25],
        "name": "x",
        "flag": True,
    }
    values = headline_values(
        metrics, ["gdice", "variants.*", "variants.*.wrong_rate", "crossing.*", "acc", "name", "flag", "missing.key"]
    )
    assert values == {
        "gdice": "13.81 ± 0.041",
        "variants.hbni": "5.8 ± 0.02",
        "variants.ssbf": "5.2 ± 0.03",
        "variants.hbni.wrong_rate": "0.022",
        "crossing.15.0.05": "3",
        "crossing.15.0.01": "None",
        "acc": "[0.5, 0.25]",
        "name": "x",
        "flag": "True",
    }


def test_report_of_jobs_without_status(tmp_path):
    (tmp_path / "0" / ".hydra").mkdir(parents=True)
    (tmp_path / "0" / ".hydra" / "overrides.yaml").write_text("- seed=1\n")
    report = multirun_report(tmp_path)
    assert "1 jobs, 0 completed." in report and "no status (running, or stopped before it started)" in report
