"""Classification steps: train the frame classifier on rendered snapshots, classify rendered sequences."""

from __future__ import annotations

import contextlib
from pathlib import Path
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import torch
from hydra.utils import instantiate
from tqdm.auto import tqdm

from classifiers import FrameClassifier, class_columns
from classifiers.data import render_images, render_sequence
from experiments.runs.artifacts import save_artifact
from hbni_infra.checks import as_int
from hbni_infra.streams import stream_seed
from hbni_infra.threads import single_thread, worker_threads


def _workers(clf: FrameClassifier) -> int:
    """Threads that embed frames side by side by default: :func:`hbni_infra.threads.worker_threads`, or one for a
    classifier set to several torch threads."""
    return worker_threads() if clf.threads in (None, 1) else 1


def train_classifier(
    classifier: Any,
    classes: list[str],
    per_class: int,
    augment: int,
    seed: int,
    progress: bool,
    workers: int | None = None,
) -> FrameClassifier:
    """Instantiate the frame classifier from its settings (the ``classifier`` block) and train it on ``per_class`` training-condition snapshots
    of each class (plus ``augment`` random crop + mirror copies of each), embedded by ``workers`` threads side by side
    (``None``: :func:`hbni_infra.threads.worker_threads`, or one for a classifier set to several torch threads; the
    same classifier for any ``workers``)."""
    clf: FrameClassifier = instantiate(classifier)
    workers = _workers(clf) if workers is None else workers
    images, labels = [], []
    for name in classes:
        snaps = render_images(name, per_class, "training", seed=seed)
        images += list(snaps)
        labels += [name] * len(snaps)
    clf.fit(images, labels, augment=augment, progress=progress, workers=workers)
    if clf.classes_ != sorted(classes):
        raise RuntimeError(f"classifier classes {clf.classes_} differ from {sorted(classes)}")
    return clf


def train_study_classifier(settings: Any, block: Any, classes: list[str], run_dir: Path) -> FrameClassifier:
    """A study's frame classifier: :func:`train_classifier` on ``block.train_per_class`` snapshots per class (plus
    ``block.augment`` copies) from the ``"train"`` stream of ``settings.seed``, on ``settings.study.threads`` threads;
    saved in ``run_dir`` as the artifact ``classifier``."""
    clf = train_classifier(
        settings.classifier,
        classes,
        block.train_per_class,
        block.augment,
        stream_seed(settings.seed, "train"),
        settings.progress,
        settings.study.threads,
    )
    save_artifact(run_dir, "classifier", clf)
    return clf


def sequence_outputs(
    clf: FrameClassifier,
    classes: list[str],
    n_seq: int,
    frames: int,
    cond,
    seed: int,
    progress: bool,
    desc: str,
    workers: int | None = None,
) -> tuple[torch.Tensor, np.ndarray]:
    """Classifier outputs ``(C, n_seq, frames, C)`` and one thumbnail strip per (class, sequence) ``[0]`` frames.

    Row ``c`` holds sequences of ``classes[c]``; output columns follow ``classes`` too (the
    classifier's own column order is alphabetical, ``clf.classes_``). ``workers`` threads (``None``:
    :func:`hbni_infra.threads.worker_threads`, or one for a classifier set to several torch threads) render and
    classify sequences side by side, each on one torch thread (rendering and the backbone release the
    GIL), so the outputs are the same for any ``workers``.
    """
    out = torch.empty(len(classes), n_seq, frames, len(classes))
    thumbs = np.empty((len(classes), n_seq), dtype=object)
    jobs = [(c, s) for c in range(len(classes)) for s in range(n_seq)]
    for (c, s), (seq, proba) in zip(jobs, _classified(clf, classes, jobs, frames, cond, seed, progress, desc, workers)):
        out[c, s] = proba
        thumbs[c, s] = seq
    return out, thumbs


def class_mix_outputs(
    clf: FrameClassifier,
    classes: list[str],
    counts: list[int],
    frames: int,
    cond,
    seed: int,
    progress: bool,
    desc: str,
    workers: int | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Classifier outputs ``(B, frames, C)`` of ``counts[c]`` sequences of each class ``classes[c]`` (``B`` their
    sum; sequence ``i`` of a class as :func:`sequence_outputs` renders it) and their true classes ``(B,)``: streams
    in a class mix of the caller's choosing. ``workers`` as for :func:`sequence_outputs`."""
    jobs = [(c, s) for c, n in enumerate(counts) for s in range(n)]
    out = torch.empty(len(jobs), frames, len(classes))
    for b, (_, proba) in enumerate(_classified(clf, classes, jobs, frames, cond, seed, progress, desc, workers)):
        out[b] = proba
    return out, torch.tensor([c for c, _ in jobs], dtype=torch.long)


def _classified(clf, classes, jobs, frames, cond, seed, progress, desc, workers):
    """``(frames, outputs)`` of each ``(class, index)`` job in order, rendered and classified by ``workers`` threads
    side by side, each on one torch thread; outputs ``(frames, C)`` in ``classes``' column order."""
    workers = as_int("workers", _workers(clf) if workers is None else workers, minimum=1)
    if workers > 1 and clf.threads not in (None, 1):
        raise ValueError(f"workers: {workers} threads need a classifier on one torch thread, it has {clf.threads}")
    order = class_columns(clf, classes)

    def classify(job: tuple[int, int]) -> tuple[np.ndarray, torch.Tensor]:
        seq = render_sequence(classes[job[0]], frames, cond, seed=seed, index=job[1])
        return seq, clf.proba(seq)[:, order]

    with single_thread() if workers > 1 else contextlib.nullcontext(), ThreadPoolExecutor(workers) as pool:
        yield from tqdm(pool.map(classify, jobs), total=len(jobs), desc=desc, unit="seq", disable=not progress)
