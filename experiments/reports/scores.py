"""Comparing scores (``{"value", "stderr"}`` entries): ratios of values, and whether one beats another outside both
standard errors."""

from __future__ import annotations


def ratio(numerator: float, denominator: float) -> float:
    """``numerator / denominator``, NaN when the denominator is 0 (a reference that earned nothing)."""
    return numerator / denominator if denominator else float("nan")


def beats(entry: dict[str, float], other: dict[str, float]) -> bool:
    """Whether ``entry``'s value beats ``other``'s by a margin outside both standard errors.

    Both are score dicts with ``value`` and ``stderr``: ``value - stderr > other value + other stderr``.
    """
    return entry["value"] - entry["stderr"] > other["value"] + other["stderr"]
