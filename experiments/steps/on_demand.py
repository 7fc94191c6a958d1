"""Held-out sequences for one process, rendered only as far as the process reads them.

A macro-observation process decides on the frames up to its decision and never reads the rest, so its
outcome ``(label, frames used)`` on a sequence is known once those frames are. The HBNI process decides
after about 5 of the mission's 30 frames, so the held-out sequences that power its value test cost a
fraction of whole ones when each is rendered and classified a block at a time (:data:`LENGTHS`) until
the process has decided on it. The frames it never reads are left as uniform outputs, which the
process does not reach.

The sequences are those of a larger bank (:class:`~experiments.steps.bank.BankSpec`, sequence ``i`` of
class ``c`` from ``(class_seed(seed, c), i)``), their frames the same values as the whole sequences'
(:func:`~experiments.steps.bank.classify_frames`), so a replay of them is a replay of the process on
those sequences.
"""

from __future__ import annotations

import os
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

import torch
from torch import Tensor
from tqdm.auto import tqdm

import hbni_pyro
from classifiers import FrameClassifier
from experiments.steps.bank import BankSpec, classify_blocks_in_worker, classify_frames, worker_pool

LENGTHS = (2, 4, 8, 16)
"""Frames rendered of a sequence the process has not decided on, in turn, before all of them."""

_TASK = 8  # sequences per worker task


def _lengths(frames: int) -> list[int]:
    return [n for n in LENGTHS if n < frames] + [frames]


class OnDemandStreams:
    """Bank sequences rendered and classified for a process, a block of frames at a time.

    The worker processes start with the first replay that renders and serve every later one (each takes seconds
    to start: torch and the classifier); :meth:`close`, or leaving a ``with`` block, ends them.

    Args:
        spec: the bank the sequences belong to (its ``sequences`` are not read: any index may be asked for).
        clf: the fitted classifier; ``classifier_path`` its saved file (loaded by the workers).
        workers: processes rendering side by side (0: in this process).
        progress: show a progress bar.
    """

    def __init__(
        self,
        spec: BankSpec,
        clf: FrameClassifier,
        classifier_path: str | os.PathLike,
        workers: int,
        progress: bool = False,
    ) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
            raise ValueError(f"workers: expected an int >= 0, got {workers!r}")
        self.spec, self.clf, self.workers, self.progress = spec, clf, workers, progress
        self._classifier_path = str(classifier_path)
        self._pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> OnDemandStreams:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the worker processes, if any started; a later replay starts new ones."""
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def _worker_pool(self) -> ProcessPoolExecutor | None:
        if self.workers and self._pool is None:
            self._pool = worker_pool(self._classifier_path, self.workers)
        return self._pool

    def replay(
        self, process: hbni_pyro.MacroObservationProcess, pool: hbni_pyro.StreamReplay, first: int, count: int
    ) -> tuple[hbni_pyro.StreamReplay, Tensor]:
        """``pool`` (``process`` replayed on ``P`` sequences per class, in ``closed_loop.as_streams`` order) with
        sequences ``first .. first + count - 1`` of every class after each class's ``P`` (the process run on the new
        streams only), and the frames rendered of each new sequence ``(C, count)`` long.

        Raises:
            ValueError: ``pool`` replays another process or another number of classes, or ``first``/``count`` are
                negative.
        """
        C, F = len(self.spec.classes), self.spec.frames
        if pool.process is not process or pool.num_classes != C:
            raise ValueError(f"pool: expected a replay of this process on {C} classes")
        if first < 0 or count < 0:
            raise ValueError(f"first, count: expected ints >= 0, got {first}, {count}")
        streams = torch.full((C, count, F, C), 1.0 / C, dtype=torch.float64)
        rendered = torch.zeros(C, count, dtype=torch.long)
        todo = [(c, i) for c in range(C) for i in range(count)]
        with tqdm(total=len(todo), desc="powered held-out", unit="seq", disable=not self.progress) as bar:
            self._render(process, todo, first, streams, rendered, bar)
        if not count:
            return pool, rendered
        new = hbni_pyro.StreamReplay(process, streams.reshape(-1, F, C), torch.arange(C).repeat_interleave(count))
        used = new.results.frames_used.view(C, count)
        if ((used > rendered) & (rendered < F)).any():
            raise RuntimeError(
                "process: run on all the new streams together, it read frames it had not read on those undecided "
                "alone (a filter whose result depends on the batch)"
            )
        P = int(pool.streams_per_class[0])
        old = torch.arange(C * P).view(C, P)
        added = C * P + torch.arange(C * count).view(C, count)
        return pool.joined(new).subset(torch.cat([old, added], dim=1).reshape(-1)), rendered

    def _render(
        self,
        process: hbni_pyro.MacroObservationProcess,
        todo: list[tuple[int, int]],
        first: int,
        streams: Tensor,
        rendered: Tensor,
        bar: tqdm,
    ) -> None:
        """Render and classify each ``(class, sequence)`` of ``todo`` a block at a time (:data:`LENGTHS`) until
        ``process`` has decided on it, writing its outputs into ``streams`` and its length into ``rendered``.

        Sequences go in tasks of :data:`_TASK`, the process runs on each task's sequences as the task ends, and those
        still undecided wait for their next block; with workers, tasks keep them busy meanwhile (a partial task is
        sent only when fewer than two per worker are queued)."""
        lengths = _lengths(self.spec.frames)
        waiting: dict[int, list[tuple[int, int]]] = {0: list(todo)}  # index into lengths -> sequences to render
        pending: dict[Future, tuple[list[tuple[int, int]], int]] = {}
        pool = self._worker_pool() if todo else None
        while pending or any(waiting.values()):
            for k in sorted(waiting):
                group = waiting[k]
                while len(group) >= _TASK or (group and len(pending) < 2 * max(self.workers, 1)):
                    task, group = group[:_TASK], group[_TASK:]
                    pending[self._submit(pool, task, first, lengths[k], rendered)] = (task, k)
                waiting[k] = group
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                task, k = pending.pop(future)
                stop = lengths[k]
                for (c, i), out in zip(task, future.result()):
                    streams[c, i, int(rendered[c, i]) : stop] = out.double()
                    rendered[c, i] = stop
                undecided = self._undecided(process, task, streams, rendered)
                waiting.setdefault(k + 1, []).extend(undecided)
                bar.update(len(task) - len(undecided))

    def _submit(
        self, pool: ProcessPoolExecutor | None, task: list[tuple[int, int]], first: int, stop: int, rendered: Tensor
    ) -> Future:
        """Frames ``rendered .. stop - 1`` of each ``(class, sequence)`` of ``task``, classified in ``pool`` (in this
        process, at once, without one)."""
        blocks = [(c, first + i, int(rendered[c, i]), stop) for c, i in task]
        if pool is not None:
            return pool.submit(classify_blocks_in_worker, self.spec, blocks)
        future: Future = Future()
        future.set_result([classify_frames(self.clf, self.spec, *block) for block in blocks])
        return future

    @staticmethod
    def _undecided(
        process: hbni_pyro.MacroObservationProcess, todo: list[tuple[int, int]], streams: Tensor, rendered: Tensor
    ) -> list[tuple[int, int]]:
        """Those of ``todo`` on which ``process`` has not decided within their rendered frames."""
        if not todo:
            return todo
        cs, idx = torch.tensor(todo).T
        result = process.run_batch(streams[cs, idx])
        undecided = result.frames_used.cpu() > rendered[cs, idx]  # it read a frame not rendered yet
        return [todo[j] for j in undecided.nonzero().flatten().tolist()]
