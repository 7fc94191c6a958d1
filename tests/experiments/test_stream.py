"""experiment=stream on a video the test writes itself: records, annotated video, strip, and the errors."""

import json
import re

import cv2
import numpy as np
import pytest
import torch
from experiment_runs import run_experiment

import hbni_pyro
from hydra.errors import ConfigCompositionException
from classifiers import FrameClassifier
from classifiers.data import render_images, render_sequence
from classifiers.sources import open_source
from experiments.schemas import build_settings, compose_config
from classifiers import classify_frames
from hbni_pyro import macro_observations

CLASSES = ["police_car", "ambulance", "food_crate"]  # not the classifier's alphabetical order, on purpose
PER_CLASS = 14


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A tiny classifier and HBNI posterior, and a 42-frame video of three objects in turn."""
    root = tmp_path_factory.mktemp("stream")
    images, labels = [], []
    for name in CLASSES:
        snaps = render_images(name, 6, "training", seed=0)
        images += list(snaps)
        labels += [name] * len(snaps)
    clf = FrameClassifier().fit(images, labels)
    order = [clf.classes_.index(n) for n in CLASSES]
    calib = torch.cat([clf.predict_proba(render_sequence(n, 10, "mission", seed=1))[:, order] for n in CLASSES])
    posterior = hbni_pyro.fit(
        calib.double(),
        torch.arange(3).repeat_interleave(10),
        class_names=CLASSES,
        num_chains=2,
        num_samples=60,
        warmup_steps=60,
        seed=0,
        progress=False,
    )
    frames = np.concatenate([render_sequence(n, PER_CLASS, "mission", seed=2) for n in CLASSES])
    video = root / "clip.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 15.0, (frames.shape[2], frames.shape[1]))
    for f in frames:
        writer.write(f)
    writer.release()
    return {
        "root": root,
        "video": video,
        "frames": frames,
        "classifier": clf.save(root / "classifier.safetensors"),
        "posterior": posterior.save(root / "posterior.safetensors"),
    }


def _args(saved, out, *extra):
    return [
        "experiment=stream",
        f"stream.source={saved['video']}",
        f"stream.classifier={saved['classifier']}",
        f"stream.posterior={saved['posterior']}",
        f"stream.classes=[{','.join(CLASSES)}]",
        "stream.max_frames=6",
        "stream.temper=0.6",
        f"hydra.run.dir={out}",
        "progress=false",
        *extra,
    ]


def test_stream_experiment_on_a_generated_video(tmp_path, saved, repo_root):
    proc = run_experiment(_args(saved, tmp_path), repo_root)
    assert f"wrote {tmp_path / 'macro_observations.jsonl'}" in proc.stdout
    records = [json.loads(line) for line in (tmp_path / "macro_observations.jsonl").read_text().splitlines()]
    # consecutive frame ranges covering the whole video; the process restarts after each record
    assert records[0]["start_frame"] == 0 and records[-1]["end_frame"] == 3 * PER_CLASS - 1
    for a, b in zip(records, records[1:]):
        assert b["start_frame"] == a["end_frame"] + 1 and b["index"] == a["index"] + 1
    for r in records:
        assert r["frames_used"] == r["end_frame"] - r["start_frame"] + 1 <= 6
        assert r["label"] == CLASSES[r["label_index"]]
        assert r["timed_out"] == (r["confidence"] < 0.95)
        assert r["timed_out"] or r["frames_used"] <= 6
    assert sum(r["stream_ended"] for r in records) <= 1 and not any(r["stream_ended"] for r in records[:-1])

    # the same records from the same decoded frames, run in this process through the batched process
    clf = FrameClassifier.load(saved["classifier"])
    process = hbni_pyro.MacroObservationProcess(
        hbni_pyro.HBNIFilter(hbni_pyro.HBNIPosterior.load(saved["posterior"]), temper=0.6), 0.95, 6
    )
    decoded = list(open_source(saved["video"]))
    order = [clf.classes_.index(n) for n in CLASSES]
    outputs = clf.predict_proba(decoded)[:, order].double()
    for r in records:
        alone = process.run_batch(outputs[None, r["start_frame"] : r["start_frame"] + 6])
        if not r["stream_ended"]:
            assert (int(alone.label[0]), int(alone.frames_used[0])) == (r["label_index"], r["frames_used"])
        assert float(alone.confidence[0]) == pytest.approx(r["confidence"], rel=1e-4) or r["stream_ended"]
    # most macro-observations of each third of the video name the object shown there
    for k, name in enumerate(CLASSES):
        inside = [r for r in records if k * PER_CLASS <= r["start_frame"] < (k + 1) * PER_CLASS]
        assert sum(r["label"] == name for r in inside) >= len(inside) / 2

    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["frames"] == 3 * PER_CLASS and metrics["macro_observations"] == len(records) and metrics["fps"] > 0
    capture = cv2.VideoCapture(str(tmp_path / "annotated.mp4"))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 3 * PER_CLASS
    ok, frame = capture.read()
    assert ok and frame.shape == saved["frames"][0].shape
    assert np.abs(frame[:20].astype(int) - saved["frames"][0][:20]).mean() > 20  # the annotation panel is drawn
    assert (tmp_path / "strip.png").stat().st_size > 20_000


def test_a_folder_of_frames_gives_the_in_process_segments(tmp_path, saved, repo_root):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(saved["frames"][:20]):
        cv2.imwrite(str(folder / f"f{i}.png"), f)
    out = tmp_path / "run"
    run_experiment(_args(saved, out, f"stream.source={folder}", "stream.annotate=[]", "stream.batch=3"), repo_root)
    records = [json.loads(line) for line in (out / "macro_observations.jsonl").read_text().splitlines()]
    assert not (out / "annotated.mp4").exists() and not (out / "strip.png").exists()
    clf = FrameClassifier.load(saved["classifier"])
    process = hbni_pyro.MacroObservationProcess(
        hbni_pyro.HBNIFilter(hbni_pyro.HBNIPosterior.load(saved["posterior"]), temper=0.6), 0.95, 6
    )
    segments = list(macro_observations(classify_frames(open_source(folder), clf, CLASSES, batch=5), process, CLASSES))
    assert len(segments) == len(records)
    for seg, rec in zip(segments, records):  # batches of 5 here, 3 there: outputs agree to float32 rounding
        ours = seg.record()
        rec = {key: rec[key] for key in ours}  # the stream's records add its frames' stamps
        assert ours.pop("confidence") == pytest.approx(rec.pop("confidence"), rel=1e-4) and ours == rec
    assert segments[-1].end == 19


@pytest.mark.parametrize(
    "override, message",
    [
        ("stream.source=/no/such/clip.mp4", "stream.source: no such video file or folder"),
        ("stream.source=null", "stream.source: expected a video file, a folder of frames or a camera index"),
        ("stream.run=/no/such/run", "stream.run: no such file or directory"),
        ("stream.posterior=/no/such.safetensors", "stream.posterior: no such file or directory"),
        ("stream.annotate=[gif]", "stream.annotate: expected a subset of ['video', 'strip', 'bag']"),
        ("stream.temper=2", "stream.temper: expected a finite number in (0, 1]"),
        ("stream.threshold=0", "stream.threshold: expected a finite number in (0, 1]"),
        ("stream.batch=0", "stream.batch: expected an int >= 1"),
        ("stream.max_input_frames=0", "stream.max_input_frames: expected an int >= 1"),
    ],
)
def test_bad_settings_are_clear_errors(saved, override, message):
    """Checked against the stream's schema before anything is loaded, naming the key."""
    cfg = compose_config(_args(saved, "unused")[:-2] + [override])
    with pytest.raises(ValueError, match=re.escape(message)):
        build_settings(cfg)


def test_a_wrong_type_fails_while_composing(saved):
    with pytest.raises(ConfigCompositionException):
        compose_config(_args(saved, "unused")[:-2] + ["stream.batch=many"])


def test_without_a_mission_run_the_default_run_is_a_clear_error(saved, tmp_path, monkeypatch):
    from experiments.studies.stream import read_settings

    cfg = compose_config(_args(saved, "unused")[:-2] + ["stream.classifier=null"])
    build_settings(cfg)  # run=latest is found when the stream starts
    monkeypatch.setenv("HBNI_PYRO_ROOT", str(tmp_path))
    with pytest.raises(
        FileNotFoundError, match=f"stream.run: no completed 'mission' run under '{tmp_path / 'outputs' / 'mission'}'"
    ):
        read_settings(build_settings(cfg))


def test_classes_that_are_not_the_posteriors_are_a_clear_error(tmp_path, saved, repo_root):
    proc = run_experiment(_args(saved, tmp_path, "stream.classes=[a,b,c]"), repo_root, check=False)
    assert proc.returncode != 0 and (
        "stream.classes: expected the posterior's classes in its column order "
        "['police_car', 'ambulance', 'food_crate'], got ['a', 'b', 'c']" in proc.stderr
    ), proc.stderr[-2000:]


def test_streaming_steps_reject_bad_input(saved):
    clf = FrameClassifier.load(saved["classifier"])
    with pytest.raises(ValueError, match="batch: expected an int >= 1, got 0"):
        next(classify_frames([], clf, CLASSES, batch=0))
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), 0.95, 6)
    with pytest.raises(ValueError, match="classes: expected 3 distinct names"):
        next(macro_observations([], process, CLASSES[:2]))
    assert list(macro_observations([], process, CLASSES)) == []


def test_a_run_that_is_not_a_mission_is_a_clear_error(tmp_path, saved, repo_root):
    other = tmp_path / "toy"
    (other / ".hydra").mkdir(parents=True)
    (other / ".hydra" / "config.yaml").write_text("name: hbni_toy\n")
    (other / "metrics.json").write_text("{}")
    (other / "status.json").write_text('{"status": "completed"}')
    proc = run_experiment(
        _args(saved, tmp_path / "out", "stream.classifier=null", "stream.posterior=null", f"stream.run={other}"),
        repo_root,
        check=False,
    )
    assert (
        proc.returncode != 0
        and f"stream.run: {str(other)!r} is not a mission run (it lacks classifier, posterior" in proc.stderr
    ), proc.stderr[-2000:]
