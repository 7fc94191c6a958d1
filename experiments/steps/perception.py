"""Perception steps: train the frame classifier on rendered snapshots, classify rendered sequences."""

from __future__ import annotations

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig
from tqdm.auto import tqdm

from classifiers import FrameClassifier, class_columns
from classifiers.data import render_images, render_sequence


def train_classifier(
    classifier: DictConfig, classes: list[str], per_class: int, augment: int, seed: int, progress: bool
) -> FrameClassifier:
    """Instantiate the frame classifier and train it on ``per_class`` training-condition snapshots
    of each class (plus ``augment`` random crop + mirror copies of each)."""
    clf: FrameClassifier = instantiate(classifier)
    images, labels = [], []
    for name in classes:
        snaps = render_images(name, per_class, "training", seed=seed)
        images += list(snaps)
        labels += [name] * len(snaps)
    clf.fit(images, labels, augment=augment, progress=progress)
    if clf.classes_ != sorted(classes):
        raise RuntimeError(f"classifier classes {clf.classes_} differ from {sorted(classes)}")
    return clf


def sequence_outputs(
    clf: FrameClassifier, classes: list[str], n_seq: int, frames: int, cond, seed: int, progress: bool, desc: str
) -> tuple[torch.Tensor, np.ndarray]:
    """Classifier outputs ``(C, n_seq, frames, C)`` and one thumbnail strip per (class, sequence) ``[0]`` frames.

    Row ``c`` holds sequences of ``classes[c]``; output columns follow ``classes`` too (the
    classifier's own column order is alphabetical, ``clf.classes_``).
    """
    order = class_columns(clf, classes)
    out = torch.empty(len(classes), n_seq, frames, len(classes))
    thumbs = np.empty((len(classes), n_seq), dtype=object)
    bar = tqdm(total=len(classes) * n_seq, desc=desc, unit="seq", disable=not progress)
    for c, name in enumerate(classes):
        for s in range(n_seq):
            seq = render_sequence(name, frames, cond, seed=seed, index=s)
            out[c, s] = clf.predict_proba(seq)[:, order]
            thumbs[c, s] = seq
            bar.update()
    bar.close()
    return out, thumbs
