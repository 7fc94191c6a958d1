"""The console script ``hbni-pyro``: signals handled from its first instruction, then :func:`experiments.run.main`.

The script imports this module, which loads only the standard library, rather than :mod:`experiments.run`, whose
imports (Hydra, torch, numba) take seconds: a signal among them ends the command at once, with one line
(:mod:`experiments.runs.signals`). ``python -m experiments.run`` does the same from the top of that module.
"""

from __future__ import annotations

from experiments.runs import signals


def main() -> None:
    """``hbni-pyro [experiment=<name>] [key=value ...] [-m ...]``: see :func:`experiments.run.main`."""
    signals.install()
    from experiments.run import main as run

    run()
