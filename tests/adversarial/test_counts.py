"""Counts and classes checked where the calibrated peer, calibration maps, folds, stop thresholds, sequence ids and
streams meet, and clear errors where they were unclear. Tiny objects: posteriors built from a few draws, streams
drawn from the paper's model."""

from __future__ import annotations

import os
import re

import pytest
import torch
from adversarial.test_names import posterior
from experiment_runs import run_experiment

import hbni_pyro
from hbni_pyro import (
    Fold,
    FrameCalibration,
    MacroObservationProcess,
    fit_frame_calibration,
    fit_stop_threshold,
    macro_observations,
    make_filter,
    sample_outputs,
)


def calibration(num_classes: int, class_names=None) -> FrameCalibration:
    return FrameCalibration(torch.eye(num_classes), torch.zeros(num_classes), class_names=class_names)


def streams(num_classes: int, per_class: int = 4, frames: int = 6) -> tuple[torch.Tensor, torch.Tensor]:
    """``(B, N, M)`` streams drawn from the paper's model, ``per_class`` of each class, and their classes."""
    truth = torch.arange(num_classes).repeat_interleave(per_class)
    g = torch.Generator().manual_seed(0)
    theta = torch.full((num_classes,), 5.0, dtype=torch.float64)
    out = sample_outputs(theta, truth.repeat_interleave(frames), g).reshape(len(truth), frames, num_classes)
    return out, truth


def test_the_calibrated_peer_refuses_a_calibration_of_other_classes_than_the_posterior():
    named = posterior(["a", "b", "c"])
    with pytest.raises(ValueError, match=re.escape("it has 3 classes ['a', 'b', 'c'], but the calibration maps 4")):
        make_filter("calibrated", named, calibration=calibration(4))
    with pytest.raises(ValueError, match=re.escape("the calibration maps 4 classes, got num_classes=3")):
        make_filter("calibrated", calibration=calibration(4), num_classes=3)
    with pytest.raises(ValueError, match=re.escape("it has 3 classes (unnamed), but num_classes is 4")):
        make_filter("ssbf", posterior(), num_classes=4)
    assert make_filter("calibrated", named, calibration=calibration(3)).class_names == ("a", "b", "c")


def test_the_calibrated_peer_says_a_path_is_not_a_calibration():
    with pytest.raises(
        TypeError, match=r"expected a FrameCalibration, got str; load a saved one with .*\.load\(path\)"
    ):
        make_filter("calibrated", calibration="x.safetensors")


def test_calibration_refuses_classes_with_no_frames():
    obs, truth = streams(3)
    frames = obs.reshape(-1, 3)
    one_class = torch.zeros(len(frames), dtype=torch.long)
    with pytest.raises(ValueError, match=re.escape("labels: no frames of class(es) ['b', 'c'] (of 3)")):
        fit_frame_calibration(frames, one_class, class_names=["a", "b", "c"])
    with pytest.raises(ValueError, match=re.escape("labels: no frames of class(es) [1, 2] (of 3)")):
        fit_frame_calibration(frames, one_class, "temperature")


def test_a_stop_refuses_folds_of_other_classes_and_streams_that_do_not_fit():
    three, truth3 = streams(3)
    four, truth4 = streams(4)
    folds = [
        Fold(make_filter("ssbf", num_classes=3), three, truth3),
        Fold(make_filter("ssbf", num_classes=4), four, truth4),
    ]
    with pytest.raises(ValueError, match=re.escape("fold 1's filter has 4 classes (unnamed), fold 0's 3 (unnamed)")):
        fit_stop_threshold(folds, None, None, 0.9)
    ssbf = make_filter("ssbf", num_classes=3)
    with pytest.raises(ValueError, match=re.escape("truth: expected shape (12,) to match obs, got (11,)")):
        fit_stop_threshold(ssbf, three, truth3[:-1], 0.9)
    with pytest.raises(ValueError, match=re.escape("filter[0].streams: expected outputs of the filter's 3 classes")):
        fit_stop_threshold([Fold(ssbf, four, truth4)], None, None, 0.9)
    with pytest.raises(ValueError, match=re.escape("truth: expected the class of every stream, got -1 (unknown)")):
        fit_stop_threshold(ssbf, three, torch.full_like(truth3, -1), 0.9)
    fitted = fit_stop_threshold(ssbf, three, truth3, 0.9)  # streams that fit: a stop on the grid, or the target
    assert fitted.stop in fitted.grid or fitted.stop == 0.9


def test_a_model_that_reads_no_sequence_ids_still_checks_them():
    obs, truth = streams(3, per_class=2, frames=3)
    frames, labels = obs.reshape(-1, 3), truth.repeat_interleave(3)
    settings = dict(num_chains=1, num_samples=5, warmup_steps=5, progress=False)
    with pytest.raises(ValueError, match=re.escape("sequence_ids: expected shape (18,) to match obs, got (17,)")):
        hbni_pyro.fit(frames, labels, model="paper", sequence_ids=torch.arange(17), **settings)
    with pytest.raises(TypeError, match="sequence_ids: expected integer sequence ids"):
        hbni_pyro.fit(frames, labels, model="confusion", sequence_ids=torch.rand(18), **settings)


def test_macro_observations_say_items_are_pairs_of_frame_and_output():
    process = MacroObservationProcess(make_filter("ssbf", num_classes=3), 0.9, 5)
    rows = [[0.8, 0.1, 0.1], [0.7, 0.2, 0.1]]
    with pytest.raises(TypeError, match=re.escape("items: expected (frame, output) pairs") + ".*item 0 is list"):
        list(macro_observations(rows, process, ["a", "b", "c"]))
    with pytest.raises(TypeError, match="item 2 is float 0.3"):
        list(macro_observations([(None, rows[0]), (None, rows[1]), 0.3], process, ["a", "b", "c"]))
    segments = list(macro_observations([(k, r) for k, r in enumerate(rows)], process, ["a", "b", "c"]))
    assert [s.name for s in segments] == ["a"] and segments[0].outputs.shape == (2, 3)


def test_a_root_that_is_a_file_is_one_config_error_naming_the_variable(tmp_path, repo_root):
    root = tmp_path / "a_file"
    root.write_text("")
    env = {**os.environ, "HBNI_PYRO_ROOT": str(root)}
    proc = run_experiment(["experiment=hbni_toy"], tmp_path, env=env, check=False)
    assert proc.returncode == 2 and proc.stderr == (
        f"config error: paths.root: HBNI_PYRO_ROOT: expected the folder that holds runs, sweeps and caches, got "
        f"the file '{root}'\n"
    )
