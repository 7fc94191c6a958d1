"""The new-place comparison on real photographs (``new_place.photos``, :mod:`classifiers.photos`).

The classifier is trained on ``"training"``-preset snapshots; the old place is the noise-model study's
``"degraded"`` camera (its labelled sequences: the same random stream as that study's calibration sequences), the new
one a darker, noisier camera with stronger casts (``new_place.photos.conditions``). The filters of
:mod:`experiments.steps.place_variants` are fitted on what each may use and their processes run on held-out
new-camera sequences (no mission to plan).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch
from hydra.utils import instantiate
from tqdm.auto import tqdm

import hbni_pyro
from classifiers import FrameClassifier, class_columns
from classifiers.photos import PHOTOS, photo_sequence, photo_snapshots
from experiments.schemas.new_place_study import NewPlace
from experiments.steps import closed_loop
from experiments.steps.bank import code_identity
from experiments.steps.place_variants import PlaceData, fit_variants, frame_accuracy, say
from hbni_infra.cache import cached
from hbni_infra.streams import stream_seed


def photo_study(settings: NewPlace, run_dir: Path) -> dict[str, Any]:
    """Every filter's process on held-out new-camera photograph sequences (right, right when it emits, timeouts,
    frames); models saved under ``run_dir / "photos"``."""
    st, seed = settings.new_place, settings.seed
    p, F = st.photos, st.frames
    counts = st.unlabelled_counts()
    key = {
        "kind": "experiments.new_place.photos",
        "classifier": dataclasses.asdict(settings.classifier),
        "code": code_identity(),
        "seed": seed,
        "new": p.camera.to_dict(),
        "sizes": [p.train_per_class, p.augment, p.old_sequences, p.test_sequences, max(st.labelled), counts, F],
    }

    def compute() -> dict[str, torch.Tensor]:
        say(settings, "photographs: training the classifier, classifying old- and new-camera sequences")
        clf: FrameClassifier = instantiate(settings.classifier)
        images = [im for name in PHOTOS for im in photo_snapshots(name, p.train_per_class, "training", seed)]
        clf.fit(images, [n for n in PHOTOS for _ in range(p.train_per_class)], augment=p.augment, progress=False)
        order = class_columns(clf, list(PHOTOS))

        def grid(per_class: list[int], camera: Any, part: str) -> list[torch.Tensor]:
            """Outputs ``(per_class[c], F, M)`` of each photograph ``c``'s sequences under ``camera``."""
            s = stream_seed(seed, "photos", part)
            return [
                torch.stack([clf.proba(photo_sequence(n, F, camera, s, index=i))[:, order] for i in range(k)])
                for n, k in tqdm(list(zip(PHOTOS, per_class)), desc=f"photos, {part}", disable=not settings.progress)
            ]

        M = len(PHOTOS)
        return {
            "old": torch.stack(grid([p.old_sequences] * M, "degraded", "calibration")),  # the noise-model study's
            "labelled": torch.stack(grid([max(st.labelled)] * M, p.camera, "new labelled")),
            "unlabelled": torch.cat(grid(counts, p.camera, "new unlabelled")),
            "unlabelled_truth": torch.arange(M).repeat_interleave(torch.tensor(counts)),
            "test": torch.stack(grid([p.test_sequences] * M, p.camera, "new held-out")),
        }

    tensors, path, hit = cached(st.cache_path, "new_place_photos", key, compute)
    if hit:
        say(settings, f"photographs: classifier outputs from the cache {path}")
    data = PlaceData.of(tensors)
    (run_dir / "photos").mkdir(exist_ok=True)
    variants = fit_variants(data, settings, stream_seed(seed, "photos"), run_dir / "photos", list(PHOTOS))
    test = tensors["test"].double()
    streams, truth = closed_loop.as_streams(test)
    return {
        "classes": list(PHOTOS),
        "conditions": p.camera.to_dict(),
        "frame_accuracy": {"old": frame_accuracy(data.old), "new": frame_accuracy(test)},
        "variants": {
            name: {
                "family": v.family,
                "K": v.K,
                "stop": v.process.threshold,
                "held_out_process": closed_loop.held_out_summary(
                    hbni_pyro.StreamReplay(v.process, streams, truth), st.threshold
                ),
            }
            for name, v in variants.items()
        },
    }
