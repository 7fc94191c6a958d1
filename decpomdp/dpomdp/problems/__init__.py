"""Standard Dec-POMDP benchmark problems shipped with the package (MADP toolbox, GPL-3.0; see README.md).

>>> from decpomdp.dpomdp import load_problem, problem_path
>>> problem_path("dectiger").name
'dectiger.dpomdp'
>>> load_problem("fireFighting_2_4_3").num_states  # read from the gzipped file
2025
"""

from __future__ import annotations

from pathlib import Path

from decpomdp.dpomdp.model import DPOMDPModel
from decpomdp.dpomdp.parser import load_dpomdp

PROBLEM_DIR = Path(__file__).resolve().parent
"""The folder that holds the shipped ``.dpomdp`` and ``.dpomdp.gz`` files."""


def problem_names() -> list[str]:
    """Names of the shipped problems (file names without ``.dpomdp`` / ``.dpomdp.gz``), sorted."""
    return sorted(p.name.split(".dpomdp")[0] for p in PROBLEM_DIR.iterdir() if ".dpomdp" in p.name)


def problem_path(name: str) -> Path:
    """Path of the shipped problem ``name`` (e.g. ``"dectiger"``; a ``.dpomdp`` suffix is allowed).

    Raises:
        KeyError: no shipped problem has that name (the message lists them).
    """
    if not isinstance(name, str):
        raise TypeError(f"name: expected a problem name (str), got {type(name).__name__}")
    stem = name.removesuffix(".gz").removesuffix(".dpomdp")
    for suffix in (".dpomdp", ".dpomdp.gz"):
        path = PROBLEM_DIR / f"{stem}{suffix}"
        if path.is_file() and path.parent == PROBLEM_DIR:
            return path
    raise KeyError(f"name: no shipped problem {name!r}; known: {', '.join(problem_names())}")


def load_problem(name: str, check_probabilities: bool = True) -> DPOMDPModel:
    """Parse the shipped problem ``name``; see :func:`problem_path` and :func:`~decpomdp.dpomdp.load_dpomdp`."""
    return load_dpomdp(problem_path(name), check_probabilities)
