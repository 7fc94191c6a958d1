"""The held-out output bank: built once, reused, rebuilt when any input changes, refused when its file lies."""

import dataclasses
import os
import shutil
import socket
import subprocess
import sys
import threading
import time

import pytest
import torch

from classifiers import FrameClassifier
from classifiers.data import get_conditions, render_images, render_sequence
from experiments.steps import bank as bank_module
from experiments.steps.bank import BankBuild, BankSpec, cache_path, class_seed, classifier_identity, fingerprint

CLASSES = ("ambulance", "police_car", "food_crate")
SHAPE = (72, 96)  # small frames keep rendering cheap; the classifier resizes its crop anyway


def _classifier(seed: int) -> FrameClassifier:
    images, labels = [], []
    for name in CLASSES:
        snaps = render_images(name, 6, "training", seed=seed, shape=SHAPE)
        images += list(snaps)
        labels += [name] * len(snaps)
    return FrameClassifier(seed=seed).fit(images, labels)


@pytest.fixture(scope="module")
def classifiers(tmp_path_factory):
    root = tmp_path_factory.mktemp("classifiers")
    out = []
    for seed in (0, 1):
        clf = _classifier(seed)
        out.append((clf, clf.save(root / f"clf{seed}.safetensors")))
    return out


def _spec(**changes) -> BankSpec:
    base = BankSpec(CLASSES, get_conditions("mission"), seed=7, sequences=2, frames=3, shape=SHAPE)
    return dataclasses.replace(base, **changes)


def test_bank_is_the_classified_rendered_sequences_and_is_reused(tmp_path, classifiers):
    clf, path = classifiers[0]
    first = BankBuild(_spec(), clf, path, tmp_path, workers=0)
    assert not first.cached
    outputs = first.result()
    assert outputs.shape == (3, 2, 3, 3) and first.path.is_file()
    order = [clf.classes_.index(n) for n in CLASSES]
    police = class_seed(7, "police_car")
    expect = clf.proba(render_sequence("police_car", 3, get_conditions("mission"), seed=police, index=1, shape=SHAPE))
    torch.testing.assert_close(outputs[1, 1], expect[:, order])  # row = class, columns in CLASSES order
    assert len({class_seed(7, name) for name in CLASSES} | {7}) == len(CLASSES) + 1  # each class its own conditions
    again = BankBuild(_spec(), clf, path, tmp_path, workers=0)
    assert again.cached and again.path == first.path
    assert torch.equal(again.result(), outputs)


def test_background_workers_build_the_same_bank(tmp_path, classifiers):
    clf, path = classifiers[0]
    inline = BankBuild(_spec(), clf, path, tmp_path / "a", workers=0).result()
    background = BankBuild(_spec(), clf, path, tmp_path / "b", workers=1, chunk=1)
    assert torch.equal(background.result(), inline)
    assert not background.building  # its workers are done


@pytest.mark.parametrize(
    "field, change",
    [
        ("classes", {"classes": ("police_car", "ambulance", "food_crate")}),
        ("conditions", {"conditions": get_conditions("mission", noise=(1.0, 2.0))}),
        ("seed", {"seed": 8}),
        ("sequences_per_class", {"sequences": 3}),
        ("frames", {"frames": 4}),
        ("frame_shape", {"shape": (64, 96)}),
    ],
)
def test_any_changed_input_is_a_new_bank(tmp_path, classifiers, field, change):
    clf, path = classifiers[0]
    old = BankBuild(_spec(), clf, path, tmp_path, workers=0)
    old.result()
    new = BankBuild(_spec(**change), clf, path, tmp_path, workers=0)
    assert not new.cached and new.path != old.path
    assert new.key[field] != old.key[field]
    assert {k for k in new.key if new.key[k] != old.key[k]} == {field}
    outputs = new.result()
    assert new.path.is_file() and old.path.is_file()  # the old bank stays for the runs that use it
    assert outputs.shape == (len(new.spec.classes), new.spec.sequences, new.spec.frames, len(new.spec.classes))


def test_another_classifier_or_its_code_is_a_new_bank(tmp_path, classifiers, monkeypatch):
    (clf0, path0), (clf1, path1) = classifiers
    old = BankBuild(_spec(), clf0, path0, tmp_path, workers=0)
    old.result()
    other = BankBuild(_spec(), clf1, path1, tmp_path, workers=0)
    assert not other.cached and other.key["classifier"] != old.key["classifier"]
    monkeypatch.setattr(bank_module, "code_identity", lambda: "another renderer or backbone")
    redrawn = BankBuild(_spec(), clf0, path0, tmp_path, workers=0)
    assert not redrawn.cached and redrawn.key["code"] == "another renderer or backbone"


def test_the_backbone_precision_is_part_of_the_classifier(classifiers):
    """The same head on the float32 backbone, or on 8-bit grids calibrated otherwise, classifies otherwise."""
    clf = classifiers[0][0]
    assert clf.precision_ == "int8"
    float_twin = FrameClassifier(**(clf.get_params() | {"precision": "float"}))
    float_twin.head_, float_twin.mean_, float_twin.scale_ = clf.head_, clf.mean_, clf.scale_
    recalibrated = FrameClassifier(**clf.get_params())
    recalibrated.head_, recalibrated.mean_, recalibrated.scale_ = clf.head_, clf.mean_, clf.scale_
    recalibrated.calibration_ = classifiers[1][0].calibration_
    identities = {classifier_identity(c) for c in (clf, float_twin, recalibrated)}
    assert len(identities) == 3


def test_a_file_recording_another_fingerprint_is_refused(tmp_path, classifiers):
    clf, path = classifiers[0]
    built = BankBuild(_spec(), clf, path, tmp_path, workers=0)
    built.result()
    wanted = fingerprint(_spec(seed=9), clf)
    shutil.copy(built.path, cache_path(tmp_path, wanted))  # a bank of seed 7 under seed 9's name
    with pytest.raises(ValueError, match="output bank .* seed was 7 there, is 9 here; refusing to reuse it"):
        BankBuild(_spec(seed=9), clf, path, tmp_path, workers=0)


def test_bad_settings_are_clear_errors(tmp_path, classifiers):
    clf, path = classifiers[0]
    with pytest.raises(ValueError, match="sequences: expected a positive int"):
        _spec(sequences=0)
    with pytest.raises(ValueError, match="classes: expected at least two distinct names"):
        _spec(classes=("ambulance", "ambulance"))
    with pytest.raises(ValueError, match="workers: expected an int >= 0"):
        BankBuild(_spec(), clf, path, tmp_path, workers=-1)
    with pytest.raises(ValueError, match="clf: the classifier is not fitted"):
        BankBuild(_spec(), FrameClassifier(), path, tmp_path)


def test_a_job_waits_for_the_bank_another_job_is_building(tmp_path, classifiers):
    clf, path = classifiers[0]
    lock = cache_path(tmp_path, fingerprint(_spec(), clf)).with_suffix(".safetensors.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    lock.write_text(f"{socket.gethostname()} {os.getpid()}")  # a live builder (this process stands in for it)
    waiting = BankBuild(_spec(), clf, path, tmp_path, workers=1)
    assert not waiting.cached and waiting._pool is None  # no second build started
    builder = BankBuild(_spec(), clf, path, tmp_path / "elsewhere", workers=0)

    def finish():  # the other job writes the bank where the waiting one looks, then lets go of the lock
        time.sleep(1.0)
        shutil.copy(_built(builder), waiting.path)
        lock.unlink()

    thread = threading.Thread(target=finish)
    thread.start()
    outputs = waiting.result()
    thread.join()
    assert torch.equal(outputs, builder.result()) and not lock.exists()


def test_a_lock_left_by_a_dead_process_is_taken_over(tmp_path, classifiers):
    clf, path = classifiers[0]
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    lock = cache_path(tmp_path, fingerprint(_spec(), clf)).with_suffix(".safetensors.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    lock.write_text(f"{socket.gethostname()} {dead.stdout.strip()}")
    build = BankBuild(_spec(), clf, path, tmp_path, workers=0)
    assert build.result().shape == (3, 2, 3, 3) and build.path.is_file() and not lock.exists()


def _built(build: BankBuild):
    build.result()
    return build.path
