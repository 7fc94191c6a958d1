"""Time and memory budgets of long searches (:func:`decpomdp.solve`), checked where the work is.

A :class:`Budget` is entered as a context (``with Budget(600.0, 2**32):``). Inside it, the searches' loops call
:func:`check`, which raises :class:`BudgetSpent` once the time is over, and code about to allocate a large table
calls :func:`reserve` with its size in bytes first, which raises :class:`BudgetSpent` when the table would not fit
the memory budget, so the table is never allocated. Anytime searches (the planner, the exact search, best responses,
coordinate ascent) catch :class:`BudgetSpent` and return the best they have; the budget stays spent, so the next
:func:`check` of their caller raises again and the search unwinds to :func:`~decpomdp.solve`, which returns the best
controller found with its bound. Structures whose size is a choice (the depth of a belief tree) call
:func:`memory_limit` and are built to fit.

Outside a budget these calls do nothing, so every function stays usable on its own. Time is wall-clock
(``time.perf_counter``); memory is counted in bytes of the tables a search builds (its estimate before allocating
them), not the process's resident size.
"""

from __future__ import annotations

import contextvars
import math
import time
from typing import Any

from tqdm.auto import tqdm

RESOURCES = ("time", "memory")
"""What a budget bounds."""
_CURRENT: contextvars.ContextVar[Budget | None] = contextvars.ContextVar("decpomdp_budget", default=None)
_BAR_EVERY = 0.5
"""Seconds between two updates of the progress bar."""


def size_text(nbytes: float) -> str:
    """``nbytes`` in words: ``"1.5 GiB"``, ``"300 MiB"``, ``"12 KiB"``."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{int(nbytes)} bytes"


class BudgetSpent(Exception):
    """The budget ended: ``resource`` is ``"time"`` or ``"memory"``; ``detail`` says what ran out where."""

    def __init__(self, resource: str, detail: str) -> None:
        super().__init__(f"{resource} budget spent: {detail}")
        self.resource, self.detail = resource, detail


class Budget:
    """A time and memory budget, active inside its ``with`` block.

    Args:
        seconds: wall-clock seconds from entering the block (``None``: no time limit).
        memory: bytes the largest table of the search may take (``None``: no memory limit).
        progress: show a progress bar over the seconds (``None``: only where stderr is a terminal); it appears after a
            second, so short searches show none.
        desc: the bar's label.

    Attributes:
        spent: the :class:`BudgetSpent` that ended the budget (``None`` while it lasts).
    """

    def __init__(
        self, seconds: float | None, memory: int | None, progress: bool | None = None, desc: str = "solve"
    ) -> None:
        self.seconds, self.memory, self.progress, self.desc = seconds, memory, progress, desc
        self.spent: BudgetSpent | None = None
        self.start = time.perf_counter()
        self._bar: Any = None
        self._shown = 0.0
        self._token: contextvars.Token | None = None

    def __enter__(self) -> Budget:
        self.start = time.perf_counter()
        self._bar = tqdm(
            total=None if self.seconds is None else round(self.seconds, 1),
            desc=self.desc,
            unit="s",
            disable=None if self.progress is None else not self.progress,
            delay=1.0,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s{postfix}"
            if self.seconds is not None
            else "{desc}: {n:.0f} s{postfix}",
        )
        self._token = _CURRENT.set(self)
        return self

    def __exit__(self, *exc: Any) -> None:
        _CURRENT.reset(self._token)
        self._advance(force=True)
        self._bar.close()

    @property
    def elapsed(self) -> float:
        """Seconds since the block was entered."""
        return time.perf_counter() - self.start

    def time_left(self) -> float:
        """Seconds left (``inf`` without a time limit; 0 once the budget is spent)."""
        if self.spent is not None:
            return 0.0
        return math.inf if self.seconds is None else max(0.0, self.seconds - self.elapsed)

    def check(self) -> None:
        """Raise :class:`BudgetSpent` if the budget is spent (now or before)."""
        self._advance()
        if self.spent is None and self.seconds is not None and self.elapsed >= self.seconds:
            self.spent = BudgetSpent("time", f"{self.seconds:g} s passed during {self.desc}")
        if self.spent is not None:
            raise self.spent

    def reserve(self, nbytes: float, what: str) -> None:
        """Raise :class:`BudgetSpent` (and end the budget) if a table of ``nbytes`` bytes, described by ``what``, would
        exceed the memory budget; then :meth:`check`."""
        if self.spent is None and self.memory is not None and nbytes > self.memory:
            self.spent = BudgetSpent(
                "memory",
                f"{what} needs {size_text(nbytes)}, more than the memory budget of {size_text(self.memory)} "
                f"(during {self.desc})",
            )
        self.check()

    def phase(self, name: str) -> None:
        """Name what the search does now (the progress bar's label, and where a spent budget says it ended)."""
        self.desc = name
        if self._bar is not None:
            self._bar.set_description_str(name, refresh=False)
        self._advance(force=True)

    def note(self, **values: float) -> None:
        """Show ``values`` (the best value, the bound) beside the progress bar."""
        if self._bar is not None:
            self._bar.set_postfix({k: f"{v:.6g}" for k, v in values.items()}, refresh=False)
            self._advance(force=True)

    def _advance(self, force: bool = False) -> None:
        if self._bar is None or self._bar.disable:
            return
        now = self.elapsed
        if force or now - self._shown >= _BAR_EVERY:
            shown = now if self.seconds is None else min(now, self.seconds)
            self._bar.update(shown - self._bar.n)
            self._shown = now


def current() -> Budget | None:
    """The budget whose block is running, if any."""
    return _CURRENT.get()


def check() -> None:
    """:meth:`Budget.check` of the running budget (nothing outside one)."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.check()


def reserve(nbytes: float, what: str) -> None:
    """:meth:`Budget.reserve` of the running budget (nothing outside one)."""
    budget = _CURRENT.get()
    if budget is not None:
        budget.reserve(nbytes, what)


def time_left() -> float:
    """Seconds left of the running budget (``inf`` outside one)."""
    budget = _CURRENT.get()
    return math.inf if budget is None else budget.time_left()


def memory_limit(default: int) -> int:
    """The smaller of ``default`` bytes and the running budget's memory (``default`` outside one): the size to build a
    structure to when its size is a choice."""
    budget = _CURRENT.get()
    return default if budget is None or budget.memory is None else min(default, budget.memory)
