"""Hydra entry points. ``python -m experiments.run experiment=<name>`` runs one study;
``experiments.load_run(run_dir)`` loads a finished run's config, metrics and fitted objects.

See ``docs/architecture.md`` for the layout and the shared steps.
"""

from experiments.artifacts import Run, latest_run, load_run

__all__ = ["Run", "latest_run", "load_run"]
