"""A bank of held-out classifier-output streams, rendered and classified once and cached on disk.

The closed-loop evaluation draws a fresh recorded stream for every "infer" MA from a bank of
mission-condition sequences that neither noise fitting nor tabulation saw. Rendering and
classifying them is the costly part, so the bank is built once and cached, keyed by everything
that produced it (:func:`fingerprint`): the classifier (a digest of its head, standardisation,
crop setting, backbone weights and precision), the code that draws and classifies frames, the class order,
the imaging conditions, the seed, the number of sequences per class, the frames per sequence, the
frame shape and the torch and OpenCV versions.

The bank is an entry of the project's one cache (:mod:`hbni_infra.cache`): the file name is a digest of
that fingerprint, a run whose inputs differ in any field builds its own bank next to the old one,
and a file recording another fingerprint is refused, naming the first field that differs.

Building runs in ``workers`` background processes (spawned, each loading the saved classifier
file), so the mission can go on fitting and planning meanwhile; ``workers=0`` builds in this
process when the result is asked for. Each sequence is rendered from its class's own seed
(:func:`class_seed`) and its index, and classified on its own, so the bank does not depend on how it
was split among workers. Its classes do not share imaging conditions (as the renderer's sequence
``i`` of every class would under one seed): a value averaged over classes then carries less of the
conditions' luck (about 1.65 times less variance on the mission, whose classes' outcomes correlate
by about 0.2 under shared conditions).

Jobs of one sweep often need the same missing bank at once: the first takes the entry's lock and
builds; the others carry on with their own stages and, when they need the bank, wait for its file.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import torch
from torch import Tensor
from tqdm.auto import tqdm

from classifiers import FrameClassifier, class_columns
from classifiers.data import FRAME_SHAPE, Conditions, render_sequence
from hbni_infra.cache import FileLock, entry_path, load_entry, source_identity, store_entry, wait_for_entry
from hbni_infra.fingerprint import digest
from hbni_infra.streams import stream_seed
from hbni_infra.threads import set_threads

_KIND = "experiments.OutputBank"
_VERSION = 3


@dataclass(frozen=True)
class BankSpec:
    """What to render: ``sequences`` sequences of ``frames`` frames per class, sequence ``i`` of class ``c`` from
    ``(class_seed(seed, classes[c]), i)``."""

    classes: tuple[str, ...]
    conditions: Conditions
    seed: int
    sequences: int
    frames: int
    shape: tuple[int, int] = FRAME_SHAPE

    def __post_init__(self) -> None:
        for name in ("sequences", "frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}: expected a positive int, got {value!r}")
        if len(set(self.classes)) != len(self.classes) or len(self.classes) < 2:
            raise ValueError(f"classes: expected at least two distinct names, got {list(self.classes)}")


def class_seed(seed: int, name: str) -> int:
    """The renderer seed of class ``name``'s bank sequences under the bank seed ``seed``."""
    return stream_seed(seed, "class", name)


def classifier_identity(clf: FrameClassifier) -> str:
    """Digest of everything that decides a classifier's outputs: head, standardisation, crop, backbone weights, and
    the backbone's precision (with its 8-bit calibration)."""
    if clf.classes_ is None:
        raise ValueError("clf: the classifier is not fitted")
    tensors, meta = clf.head_.state()
    weights = Path(clf.backbone_.weights_path).read_bytes()
    grids = clf.__dict__.get("calibration_") if clf.precision_ == "int8" else None
    return digest(
        meta,
        clf.backbone_.name,
        float(clf.padding),
        clf.mean_,
        clf.scale_,
        *(tensors[k] for k in sorted(tensors)),
        weights,
        clf.precision_,
        *(() if grids is None else (grids.scales, grids.zero_points)),
    )


def code_identity() -> str:
    """Digest of the ``classifiers`` package's source (a change to how frames are drawn or classified is a new bank)."""
    return source_identity("classifiers")


def fingerprint(spec: BankSpec, clf: FrameClassifier) -> dict[str, Any]:
    """The bank's full key: a JSON-able dict (see the module docstring)."""
    return {
        "kind": _KIND,
        "version": _VERSION,
        "classifier": classifier_identity(clf),
        "code": code_identity(),
        "classes": list(spec.classes),
        "conditions": asdict(spec.conditions),
        "seed": spec.seed,
        "sequences_per_class": spec.sequences,
        "frames": spec.frames,
        "frame_shape": list(spec.shape),
        "software": {"torch": torch.__version__, "opencv": cv2.__version__},
    }


def cache_path(cache_dir: str | os.PathLike, key: dict[str, Any]) -> Path:
    """Where the bank with fingerprint ``key`` lives in ``cache_dir``."""
    return entry_path(cache_dir, "bank", key)


def load_bank(path: str | os.PathLike, key: dict[str, Any]) -> Tensor:
    """The cached outputs ``(C, S, F, C)``; refuses a file recording another fingerprint, naming the field."""
    return _bank_outputs(load_entry(path, key, "output bank"), key, path)


def _bank_outputs(tensors: dict[str, Tensor], key: dict[str, Any], path: str | os.PathLike) -> Tensor:
    """The bank's outputs among an entry's tensors, checked against the shape ``key`` promises."""
    outputs = tensors.get("outputs")
    shape = (len(key["classes"]), key["sequences_per_class"], key["frames"], len(key["classes"]))
    if outputs is None or tuple(outputs.shape) != shape:
        raise ValueError(
            f"output bank {str(path)!r}: expected outputs of shape {shape}, got "
            f"{None if outputs is None else tuple(outputs.shape)}"
        )
    return outputs


def _chunks(spec: BankSpec, size: int) -> list[tuple[int, int, int]]:
    """``(class, first, last + 1)`` sequence ranges of at most ``size`` sequences."""
    return [
        (c, i, min(i + size, spec.sequences)) for c in range(len(spec.classes)) for i in range(0, spec.sequences, size)
    ]


_WORKER: dict[str, Any] = {}


def _load_worker(classifier_path: str) -> None:
    set_threads(1)  # the pool's processes are the parallelism
    _WORKER["clf"] = FrameClassifier.load(classifier_path)


def worker_pool(classifier_path: str | os.PathLike, workers: int) -> ProcessPoolExecutor:
    """``workers`` spawned processes, each on one thread (torch, BLAS, OpenCV) with the classifier saved at
    ``classifier_path``; they run :func:`_classify_in_worker` and :func:`classify_blocks_in_worker`."""
    if multiprocessing.get_start_method(allow_none=True) not in (None, *multiprocessing.get_all_start_methods()):
        # a job of a joblib sweep runs in a loky worker, whose start method a spawned child cannot look up
        multiprocessing.set_start_method("spawn", force=True)
    context = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(workers, mp_context=context, initializer=_load_worker, initargs=(str(classifier_path),))


def classify_frames(
    clf: FrameClassifier, spec: BankSpec, c: int, index: int, start: int = 0, stop: int | None = None
) -> Tensor:
    """Outputs ``(stop - start, C)`` of frames ``start .. stop - 1`` (default: all) of sequence ``index`` of class
    ``c``, columns in ``spec.classes`` order (the same values as those frames of the whole sequence)."""
    name = spec.classes[c]
    frames = render_sequence(
        name,
        spec.frames,
        spec.conditions,
        seed=class_seed(spec.seed, name),
        index=index,
        shape=spec.shape,
        start=start,
        stop=stop,
    )
    return clf.proba(frames)[:, class_columns(clf, spec.classes)]


def _classify(clf: FrameClassifier, spec: BankSpec, c: int, first: int, last: int) -> Tensor:
    """Outputs ``(last - first, F, C)`` of sequences ``first..last-1`` of class ``c``, columns in ``spec.classes`` order."""
    return torch.stack([classify_frames(clf, spec, c, i) for i in range(first, last)])


def _classify_in_worker(spec: BankSpec, c: int, first: int, last: int) -> Tensor:
    """:func:`_classify` in a :func:`worker_pool` process."""
    return _classify(_WORKER["clf"], spec, c, first, last)


def classify_blocks_in_worker(spec: BankSpec, blocks: list[tuple[int, int, int, int]]) -> list[Tensor]:
    """:func:`classify_frames` of each ``(class, index, start, stop)`` in a :func:`worker_pool` process."""
    return [classify_frames(_WORKER["clf"], spec, *block) for block in blocks]


class BankBuild:
    """The bank for ``spec``: loaded from ``cache_dir`` when there, else built (in the background).

    Args:
        spec: what to render.
        clf: the classifier, fitted; ``classifier_path`` is its saved file (loaded by the workers).
        cache_dir: the cache directory (created when needed).
        workers: background processes (0: build in this process inside :meth:`result`).
        chunk: sequences per task.

    Attributes:
        path: the cache file. cached: whether it was already there. key: the fingerprint.
    """

    def __init__(
        self,
        spec: BankSpec,
        clf: FrameClassifier,
        classifier_path: str | os.PathLike,
        cache_dir: str | os.PathLike,
        workers: int = 1,
        chunk: int = 4,
    ) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
            raise ValueError(f"workers: expected an int >= 0, got {workers!r}")
        self.spec, self.clf, self.workers, self.chunk = spec, clf, workers, chunk
        self.key = fingerprint(spec, clf)
        self.path = cache_path(cache_dir, self.key)
        self.cached = self.path.is_file()
        self._outputs = load_bank(self.path, self.key) if self.cached else None
        self._classifier_path = str(classifier_path)
        self._pool: ProcessPoolExecutor | None = None
        self._futures: dict[Future, tuple[int, int, int]] = {}
        self._lock = FileLock(self.path)
        if not self.cached and self._lock.acquire() and workers > 0:
            self._start_workers()

    def _start_workers(self) -> None:
        self._pool = worker_pool(self._classifier_path, self.workers)
        self._futures = {
            self._pool.submit(_classify_in_worker, self.spec, *task): task for task in _chunks(self.spec, self.chunk)
        }

    @property
    def building(self) -> bool:
        """Whether background workers are still rendering and classifying (each keeps a core busy)."""
        return self._pool is not None and any(not future.done() for future in self._futures)

    def result(self, progress: bool = False) -> Tensor:
        """The bank's outputs ``(C, S, F, C)`` float32 (waits for the build, then writes the cache)."""
        if self._outputs is None and not self._lock.held:  # another job builds it: wait for its file
            found = wait_for_entry(self.path, self.key, self._lock, "output bank")
            if found is not None:
                self._outputs = _bank_outputs(found, self.key, self.path)
        if self._outputs is not None:
            return self._outputs
        try:
            self._outputs = self._build(progress)
        finally:
            self._release()
        return self._outputs

    def _build(self, progress: bool) -> Tensor:
        spec = self.spec
        out = torch.empty(len(spec.classes), spec.sequences, spec.frames, len(spec.classes))
        tasks = _chunks(spec, self.chunk)
        with tqdm(total=len(spec.classes) * spec.sequences, desc="bank", unit="seq", disable=not progress) as bar:
            if self._pool is None:
                for c, first, last in tasks:
                    out[c, first:last] = _classify(self.clf, spec, c, first, last)
                    bar.update(last - first)
            else:
                try:
                    for future in as_completed(self._futures):
                        c, first, last = self._futures[future]
                        out[c, first:last] = future.result()
                        bar.update(last - first)
                finally:
                    self._pool.shutdown(cancel_futures=True)
        store_entry(self.path, self.key, {"outputs": out})
        return out

    def _release(self) -> None:
        self._lock.release()

    def cancel(self) -> None:
        """Stop a background build (nothing is written): its worker processes end now, and its lock is released."""
        if self._pool is not None:
            workers = list((getattr(self._pool, "_processes", None) or {}).values())  # None once shut down
            self._pool.shutdown(wait=False, cancel_futures=True)
            for process in workers:  # a running task would otherwise finish first
                process.terminate()
        self._release()
