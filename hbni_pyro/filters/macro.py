"""Semantic macro-observations: run a filter until it is confident, then report.

A :class:`MacroObservationProcess` feeds outputs to a streaming filter and stops at the first
frame where ``max_m P(m) >= threshold``, or when ``max_frames`` outputs (or the stream) are
spent, in which case it reports ``timed_out=True`` with the filter's decision at that point.

:func:`characterize` simulates many streams per true class from a generative source and
tabulates the joint distribution of ``(label, frames_used)`` given the true class: a
:class:`MacroObservationModel`, which a Dec-POSMDP planner samples from.

Devices: a process runs on its filter's device (:attr:`hbni_pyro.filters.StreamingFilter.device`);
:meth:`MacroObservationProcess.run_batch` returns its batch there, and :func:`characterize` and
:func:`tabulate` build their tables there. ``meta`` filters cannot run a process: where each stream
stops depends on values.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import torch
from torch import Tensor
from tqdm.auto import tqdm

from hbni_pyro.filters.streaming import StreamingFilter, decide
from hbni_pyro.models import noise_model
from hbni_pyro.validation import DTYPE, check_same_classes, has_values
from hbni_infra.checks import as_int, as_names, as_probability
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.streams import torch_generator

_KIND = "hbni_pyro.MacroObservationModel"


class MacroObservation(NamedTuple):
    """One macro-observation: decided label, its posterior probability, outputs consumed, and
    whether the process stopped without reaching the threshold."""

    label: int
    confidence: float
    frames_used: int
    timed_out: bool


class MacroObservationBatch(NamedTuple):
    """Macro-observations of ``B`` streams: ``label``, ``frames_used`` (LongTensor ``(B,)``),
    ``confidence`` (float64 ``(B,)``), ``timed_out`` (bool ``(B,)``)."""

    label: Tensor
    confidence: Tensor
    frames_used: Tensor
    timed_out: Tensor


def _first_crossing(conf: Tensor, label: Tensor, threshold: float) -> MacroObservationBatch:
    """Each stream's macro-observation at ``threshold`` from its filter's confidence and label after every frame
    ``(B, N)``, evaluated at least up to its first frame at ``threshold`` (the last frame: the budget spent)."""
    crossed = conf >= threshold
    crossed[:, -1] = True
    step = crossed.to(torch.int8).argmax(-1, keepdim=True)  # the first crossing
    confidence = conf.gather(1, step).squeeze(1)
    return MacroObservationBatch(
        label.gather(1, step).squeeze(1), confidence, step.squeeze(1) + 1, confidence < threshold
    )


class MacroObservationProcess:
    """Run ``filter`` on a stream until ``max_m P(m) >= threshold`` or ``max_frames`` outputs.

    Args:
        filter: any :class:`hbni_pyro.filters.StreamingFilter`.
        threshold: confidence in ``(0, 1]`` at which to stop (default 0.95, as in the paper).
        max_frames: frame budget; reaching it without the threshold gives ``timed_out=True``.
    """

    def __init__(self, filter: StreamingFilter, threshold: float = 0.95, max_frames: int = 100) -> None:
        if not isinstance(filter, StreamingFilter):
            raise TypeError(f"filter: expected a StreamingFilter, got {type(filter).__name__}")
        self.filter = filter
        self.threshold = as_probability("threshold", threshold, allow_zero=False)
        self.max_frames = as_int("max_frames", max_frames, minimum=1)

    @property
    def num_classes(self) -> int:
        return self.filter.num_classes

    @property
    def class_names(self) -> tuple[str, ...] | None:
        """The filter's class names in column order (``None`` when it has none)."""
        return self.filter.class_names

    def run(self, stream: Iterable[Any] | Tensor) -> MacroObservation:
        """Consume outputs from ``stream`` (an iterable of ``(M,)`` rows or an ``(N, M)`` tensor)
        lazily, and stop as soon as the decision is made; later rows are never read.

        Raises:
            ValueError: the stream is empty, or a row is not a probability vector of width M.
        """
        if isinstance(stream, Tensor) and stream.dim() != 2:
            raise ValueError(f"stream: expected an (N, M) tensor of outputs, got shape {tuple(stream.shape)}")
        self.filter.reset()
        probs = None
        for o in stream:
            probs = self.filter.update(o)
            confidence = float(probs.max())  # the one host read per frame: whether to stop
            if confidence >= self.threshold or self.filter.frames_seen == self.max_frames:
                return MacroObservation(
                    int(decide(probs)), confidence, self.filter.frames_seen, confidence < self.threshold
                )
        if probs is None:
            raise ValueError("stream: expected at least one output, got an empty stream")
        return MacroObservation(int(decide(probs)), float(probs.max()), self.filter.frames_seen, True)

    __call__ = run

    def run_batch(self, obs: Any) -> MacroObservationBatch:
        """Batched :meth:`run` over ``obs (B, N, M)``: the same results as running each row, on the filter's device.

        Only the first ``min(N, max_frames)`` frames are used. The posterior is evaluated in
        frame blocks of doubling length, and only for streams that have not stopped yet.
        """
        return self.run_thresholds(obs, [self.threshold])[0]

    def run_thresholds(self, obs: Any, thresholds: Sequence[float]) -> list[MacroObservationBatch]:
        """:meth:`run_batch` of this process stopping at each of ``thresholds`` instead (probabilities in ``(0, 1]``)
        on ``obs (B, N, M)``, the filter evaluated once: on the frames the highest threshold reads (a lower one
        stops no later), in frame blocks of doubling length, only for streams that have not reached it yet."""
        thresholds = [as_probability(f"thresholds[{i}]", t, allow_zero=False) for i, t in enumerate(thresholds)]
        if not thresholds:
            return []
        obs = torch.as_tensor(obs)
        if obs.dim() != 3 or obs.shape[1] < 1:
            raise ValueError(f"obs: expected shape (B, N, M) with N >= 1, got {tuple(obs.shape)}")
        stats, counts = self.filter.statistics(obs[:, : self.max_frames])
        num_streams, horizon = stats.shape[:2]
        top = max(thresholds)
        conf = torch.full((num_streams, horizon), -1.0, dtype=DTYPE, device=stats.device)  # -1: not evaluated
        label = torch.zeros(num_streams, horizon, dtype=torch.long, device=stats.device)
        active = torch.arange(num_streams, device=stats.device)
        start, width = 0, 1
        while start < horizon and active.numel():
            end = min(horizon, start + width)
            block = stats[active, start:end]
            probs = self.filter.posterior(block, counts[start:end].expand(block.shape[:-1]))  # (A, k, M)
            conf[active, start:end] = probs.max(-1).values
            label[active, start:end] = decide(probs)
            active = active[~(conf[active, start:end] >= top).any(-1)]
            start, width = end, 2 * width
        return [_first_crossing(conf, label, t) for t in thresholds]

    def __repr__(self) -> str:
        return f"MacroObservationProcess({self.filter!r}, threshold={self.threshold}, max_frames={self.max_frames})"


class MacroObservationModel:
    """Empirical law of a macro-observation process: ``P(label, frames_used | true class)``.

    Args:
        joint: ``(M, M, F)`` with ``joint[c, l, f] = P(label = l, frames_used = f + 1 | true = c)``;
            each ``joint[c]`` must sum to 1.
        timed_out: ``(M,)`` probability that the process ran out of frames, per true class.
        info: JSON-serialisable description (threshold, filter, number of simulated streams, ...).

    The tables stay on ``joint``'s device (``timed_out`` is moved there), where :meth:`sample` draws; on
    ``meta`` only their shapes are checked.
    """

    def __init__(self, joint: Any, timed_out: Any, info: dict[str, Any] | None = None, class_names: Any = None) -> None:
        joint = torch.as_tensor(joint, dtype=DTYPE)
        if joint.dim() != 3 or joint.shape[0] != joint.shape[1] or joint.shape[0] < 2 or joint.shape[2] < 1:
            raise ValueError(f"joint: expected shape (M, M, max_frames) with M >= 2, got {tuple(joint.shape)}")
        values = has_values(joint)
        if values and (not torch.isfinite(joint).all() or (joint < 0).any()):
            raise ValueError("joint: expected finite, non-negative probabilities")
        totals = joint.sum((1, 2))
        if values and ((totals - 1).abs() > 1e-9).any():
            raise ValueError(f"joint: each true class's table must sum to 1, got sums {totals.tolist()}")
        timed_out = torch.as_tensor(timed_out, dtype=DTYPE).to(joint.device)
        if timed_out.shape != joint.shape[:1]:
            raise ValueError(f"timed_out: expected shape ({joint.shape[0]},), got {tuple(timed_out.shape)}")
        if values and not ((timed_out >= 0) & (timed_out <= 1)).all():
            raise ValueError(f"timed_out: expected ({joint.shape[0]},) probabilities, got {timed_out.tolist()}")
        self.joint = joint / totals[:, None, None]
        self.timed_out = timed_out
        self.info = dict(info or {})
        self._flat = self.joint.reshape(self.num_classes, -1)
        self.class_names = as_names("class_names", class_names, self.num_classes)

    @property
    def num_classes(self) -> int:
        return self.joint.shape[0]

    @property
    def max_frames(self) -> int:
        return self.joint.shape[2]

    @property
    def confusion(self) -> Tensor:
        """``(M, M)`` ``P(label | true class)``; rows sum to 1."""
        return self.joint.sum(2)

    @property
    def frames_pmf(self) -> Tensor:
        """``(M, max_frames)`` ``P(frames_used = f + 1 | true class)``; rows sum to 1."""
        return self.joint.sum(1)

    @property
    def mean_frames(self) -> Tensor:
        """``(M,)`` expected frames used per true class."""
        support = torch.arange(1, self.max_frames + 1, dtype=DTYPE, device=self.joint.device)
        return self.frames_pmf @ support

    @property
    def accuracy(self) -> Tensor:
        """``(M,)`` probability of the right label per true class (the confusion diagonal)."""
        return self.confusion.diagonal()

    def sample(self, true_class: Any, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Draw ``(label, frames_used)`` jointly for each entry of ``true_class``.

        Args:
            true_class: integer tensor of true classes in ``[0, M)``, any shape ``S``.
            generator: the source of randomness (same state, same draws), on the tables' device.

        Returns:
            ``label`` and ``frames_used`` LongTensors of shape ``S`` (frames in ``1..max_frames``), on the
            tables' device.
        """
        if not isinstance(generator, torch.Generator):
            raise TypeError(f"generator: expected a torch.Generator, got {type(generator).__name__}")
        true_class = torch.as_tensor(true_class).to(self.joint.device)
        if true_class.is_floating_point() or true_class.dtype == torch.bool or true_class.is_complex():
            raise TypeError(f"true_class: expected an integer tensor, got dtype {true_class.dtype}")
        true_class = true_class.long()
        bad = (true_class < 0) | (true_class >= self.num_classes)
        if bad.any():
            raise ValueError(
                f"true_class: expected classes in [0, {self.num_classes}), got {int(true_class[bad].flatten()[0])}"
            )
        flat = true_class.reshape(-1)
        cell = torch.empty_like(flat)
        for c in range(self.num_classes):
            rows = (flat == c).nonzero().squeeze(-1)
            if rows.numel():
                cell[rows] = torch.multinomial(self._flat[c], rows.numel(), replacement=True, generator=generator)
        label = (cell // self.max_frames).reshape(true_class.shape)
        frames = (cell % self.max_frames + 1).reshape(true_class.shape)
        return label, frames

    def outcomes(self) -> tuple[Tensor, Tensor, Tensor]:
        """The law of ``(label, frames_used)`` per true class as outcome tables ``(probs, label, frames)``, each
        ``(M, M * max_frames)`` (cell ``l * max_frames + f`` is label ``l`` after ``f + 1`` frames), on the CPU:
        what a compiled simulator samples from (``decpomdp.engine``)."""
        cells = torch.arange(self.num_classes * self.max_frames).expand(self.num_classes, -1)
        return self._flat.to("cpu", copy=True), cells // self.max_frames, cells % self.max_frames + 1

    def reordered(self, class_names: Any) -> "MacroObservationModel":
        """The same law with classes (true and reported) in the order of ``class_names``, a reordering of its own.

        Raises:
            ValueError: the table has no names, or ``class_names`` is not a reordering of them (both lists named).
        """
        names = as_names("class_names", class_names, self.num_classes)
        if self.class_names is None or names is None or sorted(names) != sorted(self.class_names):
            raise ValueError(
                f"class_names: expected a reordering of the table's classes {self.class_names}, got "
                f"{None if names is None else list(names)}"
            )
        order = torch.tensor([self.class_names.index(n) for n in names], device=self.joint.device)
        return MacroObservationModel(self.joint[order][:, order], self.timed_out[order], self.info, names)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the tables and ``info`` to one safetensors file, atomically (from any device; read back onto the CPU)."""
        return save_tensors(
            path,
            _KIND,
            {"joint": self.joint.cpu(), "timed_out": self.timed_out.cpu()},
            {"info": self.info, "class_names": None if self.class_names is None else list(self.class_names)},
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> "MacroObservationModel":
        """Read a file written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, meta = load_tensors(path, _KIND)
        try:
            return cls(tensors["joint"], tensors["timed_out"], meta.get("info", {}), meta.get("class_names"))
        except KeyError as exc:
            raise ValueError(f"path: {str(path)!r} is an incomplete saved {_KIND} (missing {exc})") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None

    def __repr__(self) -> str:
        acc = ", ".join(f"{float(a):.3f}" for a in self.accuracy)
        mean = ", ".join(f"{float(f):.2f}" for f in self.mean_frames)
        return f"MacroObservationModel(M={self.num_classes}, accuracy=[{acc}], mean frames=[{mean}])"


def characterize(
    process: MacroObservationProcess,
    generative: Any,
    num_streams: int,
    seed: int,
    *,
    progress: bool = False,
) -> MacroObservationModel:
    """Tabulate a process's ``P(label, frames_used | true class)`` by simulation.

    Args:
        process: the macro-observation process to characterise.
        generative: where streams come from (a named one must name the process's classes in its order; the
            table takes the names of either): an :class:`hbni_pyro.HBNIPosterior` of any noise
            model (its posterior predictive of a new object, :meth:`~hbni_pyro.HBNIPosterior.sample_streams`:
            each stream takes one posterior draw, then ``max_frames`` outputs given it, sharing one
            look under the sequence model, about which they scatter with its ``frame_correlation``), anything else with ``theta_draws() -> (S, M)`` (taken
            as the paper's model) or a true theta tensor ``(M,)``.
        num_streams: streams simulated per true class.
        seed: same seed, same table.
        progress: show a progress bar over classes.

    Streams are drawn on the device of ``generative`` and filtered on the process's; the table lives there.
    """
    if not isinstance(process, MacroObservationProcess):
        raise TypeError(f"process: expected a MacroObservationProcess, got {type(process).__name__}")
    num_streams = as_int("num_streams", num_streams, minimum=1)
    names = getattr(generative, "class_names", None)
    if process.class_names is not None and names is not None:
        check_same_classes(process.class_names, names, "the process's posterior", "generative")
    streams, source, device = _stream_sampler(generative, process.num_classes)
    M, T = process.num_classes, process.max_frames
    g = torch_generator(seed, device)
    results = []
    for c in tqdm(range(M), desc="characterize", disable=not progress):
        results.append(process.run_batch(streams(c, num_streams, T, g)))
    truth = torch.arange(M, device=results[0].label.device).repeat_interleave(num_streams)
    batch = MacroObservationBatch(*(torch.cat(parts) for parts in zip(*results)))
    info = {"num_streams": num_streams, "seed": seed, "generative": source}
    return _table(process, batch, truth, info, process.class_names or names)


def tabulate(process: MacroObservationProcess, streams: Any, true_class: Any) -> MacroObservationModel:
    """Tabulate a process's ``P(label, frames_used | true class)`` from recorded output streams.

    Args:
        process: the macro-observation process to characterise.
        streams: ``(B, N, M)`` recorded classifier outputs with ``N >= process.max_frames``
            (e.g. real classifier outputs on held-out sequences).
        true_class: ``(B,)`` true class of each stream; every class must appear at least once.
    """
    if not isinstance(process, MacroObservationProcess):
        raise TypeError(f"process: expected a MacroObservationProcess, got {type(process).__name__}")
    truth = torch.as_tensor(true_class)
    if truth.is_floating_point() or truth.dim() != 1:
        raise TypeError(
            f"true_class: expected a 1-D integer tensor, got dtype {truth.dtype} and shape {tuple(truth.shape)}"
        )
    batch = process.run_batch(streams)
    if truth.shape[0] != batch.label.shape[0]:
        raise ValueError(f"true_class: expected {batch.label.shape[0]} entries to match streams, got {truth.shape[0]}")
    outside = sorted({c for c in truth.tolist() if not 0 <= c < process.num_classes})
    if outside:
        raise ValueError(f"true_class: {outside[0]} is out of range: expected classes in [0, {process.num_classes})")
    missing = sorted(set(range(process.num_classes)) - set(truth.tolist()))
    if missing:
        raise ValueError(
            f"true_class: expected every class in [0, {process.num_classes}) at least once; missing {missing}"
        )
    info = {"num_streams": int(truth.numel()), "generative": "recorded streams"}
    return _table(process, batch, truth.long().to(batch.label.device), info)


def _table(
    process: MacroObservationProcess,
    batch: MacroObservationBatch,
    truth: Tensor,
    info: dict,
    class_names: tuple[str, ...] | None = None,
) -> MacroObservationModel:
    """Empirical ``(M, M, max_frames)`` joint table of ``(label, frames_used)`` per true class, on the batch's device,
    named ``class_names`` (``None``: the process's names)."""
    M, T = process.num_classes, process.max_frames
    like = dict(dtype=DTYPE, device=truth.device)
    counts = torch.zeros(M, M * T, **like)
    counts.index_put_(
        (truth, batch.label * T + batch.frames_used - 1), torch.ones(truth.shape[0], **like), accumulate=True
    )
    per_class = counts.sum(-1, keepdim=True)
    timed_out = torch.zeros(M, **like).index_add_(0, truth, batch.timed_out.to(DTYPE)) / per_class.squeeze(-1)
    info = {"threshold": process.threshold, "max_frames": T, "filter": repr(process.filter), **info}
    names = process.class_names if class_names is None else class_names
    return MacroObservationModel((counts / per_class).reshape(M, M, T), timed_out, info, names)


StreamSampler = Callable[[int, int, int, torch.Generator], Tensor]
"""``(true_class, num_streams, num_frames, generator) -> (num_streams, num_frames, M)`` output streams."""


def _stream_sampler(generative: Any, num_classes: int) -> tuple[StreamSampler, str, torch.device]:
    """How :func:`characterize` draws streams from ``generative``, how its table names the source, and on which
    device the streams are drawn."""
    if callable(getattr(generative, "sample_streams", None)) and hasattr(generative, "model"):
        if generative.num_classes != num_classes:
            raise ValueError(
                f"generative: expected a posterior over {num_classes} classes, got {generative.num_classes}"
            )

        def posterior_streams(c: int, n: int, T: int, g: torch.Generator) -> Tensor:
            return generative.sample_streams(c, n, T, generator=g)

        return (
            posterior_streams,
            f"posterior predictive ({generative.model} model)",
            getattr(generative, "device", torch.device("cpu")),
        )
    theta, source = _generative_theta(generative, num_classes)

    def theta_streams(c: int, n: int, T: int, g: torch.Generator) -> Tensor:
        draws = theta[torch.randint(theta.shape[0], (n,), generator=g, device=theta.device)]
        return noise_model("paper").sample_streams({"theta": draws}, c, T, g)

    return theta_streams, source, theta.device


def _generative_theta(generative: Any, num_classes: int) -> tuple[Tensor, str]:
    if callable(getattr(generative, "theta_draws", None)):
        theta = torch.as_tensor(generative.theta_draws(), dtype=DTYPE)
        source = "posterior predictive"
    elif isinstance(generative, (Tensor, list, tuple)):
        theta = torch.as_tensor(generative, dtype=DTYPE)
        if theta.dim() != 1:
            raise ValueError(f"generative: expected a true theta of shape (M,), got {tuple(theta.shape)}")
        theta = theta.unsqueeze(0)
        source = f"true theta {theta[0].tolist()}"
    else:
        raise TypeError(
            f"generative: expected an HBNIPosterior or a theta tensor (M,), got {type(generative).__name__}"
        )
    if theta.shape[-1] != num_classes:
        raise ValueError(f"generative: expected theta for {num_classes} classes, got {theta.shape[-1]}")
    if not torch.isfinite(theta).all() or (theta <= 0).any():
        raise ValueError("generative: theta must be finite and > 0")
    return theta, source
