"""The noise-model comparison's data: labelled classifier outputs of each imaging condition, split into calibration
and held-out sequences.

- :func:`mission_outputs`: the disaster-relief objects rendered under each of ``study.conditions`` (the mission
  conditions and the in-flight preset), the frame classifier trained on training-condition snapshots;
- :func:`folder_outputs`: a user's image folder (``study.images``);
- :func:`photo_outputs`: real photographs under a moving, dim, blurred and occluded camera (``study.photos``,
  :mod:`classifiers.photos`).

Rendered and photographed outputs are cached on disk by everything that decides them (:func:`hbni_infra.cache.cached`).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from pathlib import Path
from typing import Any, Callable

import torch
from hydra.utils import instantiate
from tqdm.auto import tqdm

from classifiers import FrameClassifier, class_columns
from classifiers.data import ImageFolder, get_conditions
from classifiers.photos import PHOTOS, photo_sequence, photo_snapshots
from decpomdp.domains.disaster_relief import CLASSES
from experiments.runs.artifacts import save_artifact
from experiments.runs.clock import StageClock
from experiments.schemas.noise_studies import NoiseModels
from experiments.steps.classification import sequence_outputs, train_classifier
from hbni_infra.cache import cached, source_identity
from hbni_infra.streams import stream_seed

Outputs = tuple[torch.Tensor, torch.Tensor]
"""``(calibration, held-out)`` classifier outputs ``(C, S, F, C)``: ``S`` sequences of ``F`` frames per class."""


def _cache_key(classes: Any, settings: NoiseModels) -> dict[str, Any]:
    """What decides a condition's outputs besides its sizes: the classes, the classifier's settings and code (the
    renderer's included) and the seed."""
    return {
        "classes": list(classes),
        "classifier": dataclasses.asdict(settings.classifier),
        "code": source_identity("classifiers"),
        "seed": settings.seed,
    }


def mission_outputs(settings: NoiseModels, clock: StageClock, run_dir: Path) -> dict[str, Outputs]:
    """The outputs of every rendered imaging condition, from the cache when a run with the same inputs stored them
    (the classifier is trained only if needed)."""
    m, seed, progress = settings.study.mission, settings.seed, settings.progress
    base = {
        **_cache_key(CLASSES, settings),
        "train_per_class": m.train_per_class,
        "augment": m.augment,
        "frames": m.frames,
        "calib_sequences": m.calib_sequences,
        "test_sequences": m.test_sequences,
    }
    clf: list[FrameClassifier] = []

    def classifier() -> FrameClassifier:
        if not clf:
            clock.say("training the frame classifier on training-condition snapshots")
            clf.append(train_classifier(settings.classifier, CLASSES, m.train_per_class, m.augment, seed, progress))
            save_artifact(run_dir, "classifier", clf[0])
        return clf[0]

    out = {}
    for name, overrides in settings.study.conditions.items():
        conditions = get_conditions("mission", **(overrides or {}))
        compute = partial(_classify_condition, classifier, name, conditions, settings, clock)
        tensors, path, hit = cached(
            settings.study.cache_dir, f"noise_models_{name}", {**base, "conditions": conditions.to_dict()}, compute
        )
        if hit:
            clock.say(f"{name}: classifier outputs from the cache {path}")
        out[name] = (tensors["calibration"], tensors["held_out"])
    return out


def _classify_condition(
    classifier: Callable[[], FrameClassifier], name: str, conditions: Any, settings: NoiseModels, clock: StageClock
) -> dict[str, torch.Tensor]:
    """Render and classify one condition's calibration and held-out sequences (their own random streams)."""
    clock.say(f"classifying {name} sequences")
    m, seed, progress = settings.study.mission, settings.seed, settings.progress
    f = classifier()
    calib = sequence_outputs(
        f,
        CLASSES,
        m.calib_sequences,
        m.frames,
        conditions,
        stream_seed(seed, "calibration"),
        progress,
        f"{name} calibration",
    )[0]
    held = sequence_outputs(
        f,
        CLASSES,
        m.test_sequences,
        m.frames,
        conditions,
        stream_seed(seed, "held-out"),
        progress,
        f"{name} held-out",
    )[0]
    return {"calibration": calib.double(), "held_out": held.double()}


def folder_outputs(settings: NoiseModels, clock: StageClock) -> Outputs:
    """Outputs of a user's image folder: the classifier trained on ``<images>/train/<class>/*``, then
    every sequence ``<images>/sequences/<class>/<sequence>/*`` (frames in name order, the first
    ``study.mission.frames`` of each) classified; each class's first ``images_calibration`` share
    of sequences (in name order) is the calibration set, the rest held out."""
    root = Path(settings.study.images)
    frames = settings.study.mission.frames
    clock.say(f"training the frame classifier on {root / 'train'}")
    train = ImageFolder(root / "train")
    images, idx = train.load()
    clf: FrameClassifier = instantiate(settings.classifier)
    clf.fit(images, [train.classes[i] for i in idx], augment=settings.study.mission.augment, progress=settings.progress)
    seq_root = root / "sequences"
    classes = sorted(p.name for p in seq_root.iterdir() if p.is_dir()) if seq_root.is_dir() else []
    if classes != train.classes:
        raise ValueError(
            f"study.images: {str(seq_root)!r} must hold one folder per class of {train.classes}, found {classes}"
        )
    order = class_columns(clf, classes)
    per_class = []
    for name in classes:
        seqs = sorted(p for p in (seq_root / name).iterdir() if p.is_dir())
        outs = []
        for p in tqdm(seqs, desc=f"images {name}", disable=not settings.progress):
            frames_img = ImageFolder(p).load()[0]
            if len(frames_img) < frames:
                raise ValueError(
                    f"study.images: sequence {str(p)!r} has {len(frames_img)} frames, expected at least {frames}"
                )
            outs.append(clf.predict_proba(frames_img[:frames])[:, order].double())
        per_class.append(torch.stack(outs) if outs else torch.empty(0))
    counts = {len(p) for p in per_class}
    if len(counts) != 1 or 0 in counts or min(counts) < 2:
        raise ValueError(
            f"study.images: expected the same number (>= 2) of sequences per class, got {[len(p) for p in per_class]}"
        )
    outputs = torch.stack(per_class)  # (C, S, F, C)
    split = max(1, min(outputs.shape[1] - 1, round(settings.study.images_calibration * outputs.shape[1])))
    return outputs[:, :split], outputs[:, split:]


def photo_outputs(settings: NoiseModels, clock: StageClock, run_dir: Path) -> Outputs:
    """The outputs of the photographs of :data:`classifiers.photos.PHOTOS`: the classifier trained on
    ``"training"``-preset snapshots, the sequences in the ``"degraded"`` preset (calibration and held-out on their
    own random streams); cached like the rendered conditions."""
    p, seed, progress = settings.study.photos, settings.seed, settings.progress
    key = {**_cache_key(PHOTOS, settings), **dataclasses.asdict(p)}

    def compute() -> dict[str, torch.Tensor]:
        clock.say("photos: training the frame classifier on training-preset snapshots")
        clf: FrameClassifier = instantiate(settings.classifier)
        images = [im for name in PHOTOS for im in photo_snapshots(name, p.train_per_class, "training", seed)]
        clf.fit(
            images, [name for name in PHOTOS for _ in range(p.train_per_class)], augment=p.augment, progress=progress
        )
        save_artifact(run_dir, "classifier_photos", clf)
        order = class_columns(clf, list(PHOTOS))
        out = {}
        for part, count in (("calibration", p.calib_sequences), ("held_out", p.test_sequences)):
            part_seed = stream_seed(seed, "photos", part)
            seqs = [
                [
                    clf.predict_proba(photo_sequence(name, p.frames, "degraded", part_seed, index=i))[:, order]
                    for i in tqdm(range(count), desc=f"photos {part} {name}", disable=not progress)
                ]
                for name in PHOTOS
            ]
            out[part] = torch.stack([torch.stack(row) for row in seqs]).double()
        return out

    tensors, path, hit = cached(settings.study.cache_dir, "noise_models_photos", key, compute)
    if hit:
        clock.say(f"photos: classifier outputs from the cache {path}")
    return tensors["calibration"], tensors["held_out"]
