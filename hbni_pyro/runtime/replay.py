"""Closed-loop perception: a planner's "infer" MA answered by recorded streams run through a real process.

:class:`StreamReplay` holds a bank of recorded classifier-output streams with their true classes
and a :class:`~hbni_pyro.MacroObservationProcess` (a filter, a threshold, a frame budget). Each
inference of an object of class ``c`` draws one stream of class ``c`` uniformly from the bank and
reports what the process decides on it: ``(label, frames_used)``. It has ``num_classes`` and
``sample(true_class, generator)``, so a Dec-POSMDP domain takes it wherever it takes a tabulated
:class:`~hbni_pyro.MacroObservationModel` (``decpomdp.perception.PerceptionModel``), and a policy
planned on a table is executed on streams the table never saw.

The process is a deterministic function of the stream, so every bank stream is run through it once,
at construction (batched, :meth:`MacroObservationProcess.run_batch`, which equals running each
stream alone); a draw then replays its stream's result. :meth:`StreamReplay.draw` also says which
stream each inference used, and :meth:`StreamReplay.subset` replays part of the bank without running
the process again (a bootstrap over the bank's sequences), and :meth:`StreamReplay.joined` two banks as one.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from hbni_pyro.filters.macro import MacroObservationBatch, MacroObservationProcess


class StreamReplay:
    """Perception by recorded streams of each true class, run through ``process``.

    Args:
        process: the macro-observation process the robot runs.
        streams: ``(B, N, M)`` recorded classifier outputs, ``N >= 1`` (the process reads at most
            ``process.max_frames`` of each).
        true_class: ``(B,)`` integer true class of each stream; every class needs at least one stream.

    Attributes:
        results: the process's :class:`MacroObservationBatch` on every stream, ``(B,)`` each, on the CPU
            (the process runs on its filter's device; draws are table look-ups).
        true_class: ``(B,)`` long.
    """

    def __init__(self, process: MacroObservationProcess, streams: Any, true_class: Any) -> None:
        if not isinstance(process, MacroObservationProcess):
            raise TypeError(f"process: expected a MacroObservationProcess, got {type(process).__name__}")
        streams = torch.as_tensor(streams)
        truth = torch.as_tensor(true_class)
        if truth.is_floating_point() or truth.dtype == torch.bool or truth.dim() != 1:
            raise TypeError(
                f"true_class: expected a 1-D integer tensor, got dtype {truth.dtype} and shape {tuple(truth.shape)}"
            )
        if streams.dim() != 3 or streams.shape[0] != truth.shape[0]:
            raise ValueError(
                f"streams: expected shape ({truth.shape[0]}, N, {process.num_classes}) to match "
                f"true_class, got {tuple(streams.shape)}"
            )
        truth = truth.long()
        M = process.num_classes
        if ((truth < 0) | (truth >= M)).any():
            raise ValueError(f"true_class: expected classes in [0, {M})")
        _check_every_class(truth, M)
        self._setup(process, truth, MacroObservationBatch(*(field.cpu() for field in process.run_batch(streams))))

    def _setup(self, process: MacroObservationProcess, truth: Tensor, results: MacroObservationBatch) -> None:
        self.process = process
        self.num_classes = process.num_classes
        self.true_class = truth
        self.results = results
        self._counts = torch.bincount(truth, minlength=self.num_classes)
        self._pool = torch.argsort(truth, stable=True)  # streams grouped by class, bank order within a class
        self._offset = torch.cumsum(self._counts, 0) - self._counts  # first pool position of each class

    @property
    def class_names(self) -> tuple[str, ...] | None:
        """The process's class names in label order (``None`` when its filter has none)."""
        return self.process.class_names

    def subset(self, index: Any) -> StreamReplay:
        """A replay of the bank streams ``index`` (long ``(K,)``, repeats allowed): their results, not rerun.

        Raises:
            TypeError: ``index`` is not a 1-D integer tensor.
            ValueError: an index out of range, or a class left without a stream.
        """
        index = torch.as_tensor(index)
        if index.is_floating_point() or index.dim() != 1:
            raise TypeError(
                f"index: expected a 1-D integer tensor, got dtype {index.dtype} and shape {tuple(index.shape)}"
            )
        B = self.true_class.shape[0]
        if index.numel() and (int(index.min()) < 0 or int(index.max()) >= B):
            raise ValueError(f"index: expected stream indices in [0, {B})")
        index = index.long()
        truth = self.true_class[index]
        _check_every_class(truth, self.num_classes)
        part = StreamReplay.__new__(StreamReplay)
        part._setup(self.process, truth, MacroObservationBatch(*(field[index] for field in self.results)))
        return part

    def joined(self, other: StreamReplay) -> StreamReplay:
        """A replay of this replay's bank streams followed by ``other``'s: their results, not rerun.

        Raises:
            ValueError: ``other`` replays another process.
        """
        if not isinstance(other, StreamReplay) or other.process is not self.process:
            raise ValueError("other: expected a StreamReplay of the same process")
        both = StreamReplay.__new__(StreamReplay)
        results = MacroObservationBatch(*(torch.cat([a, b]) for a, b in zip(self.results, other.results)))
        both._setup(self.process, torch.cat([self.true_class, other.true_class]), results)
        return both

    @property
    def streams_per_class(self) -> Tensor:
        """``(M,)`` bank streams of each class."""
        return self._counts.clone()

    def draw(self, true_class: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        """For each object, a uniformly drawn bank stream of its class and the process's result on it.

        Args:
            true_class: long ``(B,)`` classes in ``[0, M)``.
            generator: the only source of randomness (one uniform per object).

        Returns:
            ``label``, ``frames_used`` and the bank index of the stream used, long ``(B,)`` each.
        """
        if not isinstance(generator, torch.Generator):
            raise TypeError(f"generator: expected a torch.Generator, got {type(generator).__name__}")
        if not isinstance(true_class, Tensor) or true_class.dtype != torch.long or true_class.dim() != 1:
            raise TypeError(f"true_class: expected a long tensor of shape (B,), got {true_class!r:.80}")
        if true_class.numel() and (int(true_class.min()) < 0 or int(true_class.max()) >= self.num_classes):
            raise ValueError(f"true_class: entries must lie in [0, {self.num_classes})")
        u = torch.rand(true_class.shape, generator=generator, dtype=torch.float64)
        count = self._counts[true_class]
        pick = (u * count).long().clamp_(max=count - 1)  # uniform in [0, count)
        stream = self._pool[self._offset[true_class] + pick]
        return self.results.label[stream], self.results.frames_used[stream], stream

    def outcomes(self) -> tuple[Tensor, Tensor, Tensor]:
        """The law of a draw's ``(label, frames_used)`` per true class as outcome tables ``(probs, label,
        frames)``, each ``(M, K)`` with ``K`` the most streams of one class: entry ``j < count`` of class ``c``
        is its ``j``-th bank stream (probability ``1 / count``), the rest are padding of probability 0.
        What a compiled simulator samples from (``decpomdp.engine``)."""
        K = int(self._counts.max())
        j = torch.arange(K)
        live = j[None, :] < self._counts[:, None]
        stream = self._pool[(self._offset[:, None] + j[None, :]).clamp_(max=self._pool.numel() - 1)]
        probs = torch.where(live, 1.0 / self._counts[:, None].to(torch.float64), 0.0)
        label = torch.where(live, self.results.label[stream], 0)
        frames = torch.where(live, self.results.frames_used[stream], 1)
        return probs, label, frames

    def sample(self, true_class: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """``(label, frames_used)`` of fresh draws (:meth:`draw` without the stream index)."""
        label, frames, _ = self.draw(true_class, generator)
        return label, frames

    def __repr__(self) -> str:
        return f"StreamReplay({self.process!r}, streams per class={self._counts.tolist()})"


def _check_every_class(truth: Tensor, num_classes: int) -> None:
    counts = torch.bincount(truth, minlength=num_classes)
    if (counts == 0).any():
        raise ValueError(
            f"true_class: every class needs a stream; none for {(counts == 0).nonzero().flatten().tolist()}"
        )
