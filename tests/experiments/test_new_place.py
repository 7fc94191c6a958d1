"""The new-place study through the real entry point with tiny settings: metrics, acceptance cells, figures, report,
artefacts, and its config's checks."""

import json

import pytest
from experiment_runs import run_experiment
from new_place_tiny import TINY_NEW_PLACE

from experiments.schemas import compose_settings
from hbni_pyro import HBNIPosterior


@pytest.fixture(scope="module")
def new_place_run(tmp_path_factory, repo_root):
    run_dir = tmp_path_factory.mktemp("new_place")
    run_experiment(["experiment=new_place", *TINY_NEW_PLACE, f"hydra.run.dir={run_dir}"], repo_root)
    return run_dir


def test_new_place_writes_every_variant_acceptance_and_report(new_place_run):
    metrics = json.loads((new_place_run / "metrics.json").read_text())
    names = {"perfect", "hbni_old", "calibrated_K0", "hbni_K0", "calibrated_K2", "hbni_K2"}
    assert set(metrics["variants"]) == names
    for name in names - {"perfect"}:
        entry = metrics["variants"][name]
        assert {"value", "stderr", "stream_stderr", "total_stderr"} <= set(entry["executed"])
        process = entry["held_out_process"]
        assert process["threshold"] == 0.95 and process["streams"] == 12 and 0 <= process["timeout_rate"] <= 1
        assert entry["family"] in ("hbni", "calibrated", "hbni_old")
    assert metrics["variants"]["hbni_K2"]["stop"]["fitted_on"] == "2 labelled + 12 unlabelled new-place streams"
    assert metrics["variants"]["hbni_K0"]["held_out_process"]["stop"] == metrics["variants"]["hbni_K0"]["stop"]["stop"]
    assert set(metrics["acceptance"]) == {"K0", "K2"}
    assert set(metrics["acceptance"]["K0"]["checks"]) == {
        "above_peer_by_2_stderr",
        "above_old_place_hbni",
        "honest",
        "timeouts_at_most_0.1",
    }
    assert sum(metrics["unlabelled"]["mix"]) == 12 and set(metrics["unlabelled"]["fitted_mix"]) == {
        "hbni_K0",
        "hbni_K2",
    }
    photos = metrics["photos"]["variants"]
    assert set(photos) == names - {"perfect"} and photos["hbni_K0"]["held_out_process"]["streams"] == 12
    report = (new_place_run / "report.md").read_text()
    assert "## Acceptance" in report and "## Photographs, a darker camera" in report
    for png in ("new_place.png", "new_place_photos.png"):
        assert (new_place_run / png).stat().st_size > 10_000 and f"]({png})" in report
    adapted = HBNIPosterior.load(new_place_run / "posterior_K0.safetensors")
    assert adapted.info["shift_prior"]["shift_sd"] == 0.15 and adapted.class_names == tuple(metrics["classes"])
    assert (new_place_run / "photos" / "posterior_K2.safetensors").is_file()


@pytest.mark.parametrize(
    "override, message",
    [
        ("new_place.labelled=[2,0]", "labelled: expected distinct"),
        ("new_place.mix=[1,1]", "mix: expected 6 positive weights"),
        ("new_place.new.conditions={gain:[0.5,0.1]}", "gain: expected low <= high"),
        ("new_place.old.stop_folds=60", "stop_folds: expected at most sequences=48"),
        ("new_place.unlabelled=3", "unlabelled: expected an int >= 6"),
        ("new_place.shift_sd=0", "shift_sd"),
    ],
)
def test_new_place_config_is_checked(override, message):
    with pytest.raises(ValueError, match=message):
        compose_settings(["experiment=new_place", override])
