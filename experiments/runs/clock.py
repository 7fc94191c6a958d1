"""A run's stage clock: wall and CPU seconds of the main process per stage, and its progress messages."""

from __future__ import annotations

import time

from tqdm.auto import tqdm


class StageClock:
    """Wall and CPU seconds of the main process per stage of the experiment ``name`` (its messages' prefix); a stage
    lasts until the next one starts."""

    def __init__(self, name: str, progress: bool) -> None:
        self.name, self.progress = name, progress
        self.marks: list[tuple[str, float, float]] = []  # (stage, wall, CPU) at its start

    def start(self, stage: str, message: str) -> None:
        """Begin ``stage`` (ending the previous one) and :meth:`say` ``message``."""
        self.marks.append((stage, time.perf_counter(), time.process_time()))
        self.say(message)

    def say(self, message: str) -> None:
        """Print ``message`` when showing progress."""
        if self.progress:
            tqdm.write(f"[{self.name}] {message}")

    def seconds(self) -> dict[str, dict[str, float]]:
        """``{stage: {"wall": s, "cpu": s}}`` up to now."""
        ends = [mark[1:] for mark in self.marks[1:]] + [(time.perf_counter(), time.process_time())]
        return {
            stage: {"wall": wall_end - wall, "cpu": cpu_end - cpu}
            for (stage, wall, cpu), (wall_end, cpu_end) in zip(self.marks, ends)
        }
