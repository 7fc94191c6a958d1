"""Hydra experiments. ``hbni-pyro experiment=<name>`` (or ``python -m experiments.run``) runs one study;
``experiments.load_run(run_dir)`` loads a finished run's config, metrics and fitted objects.

Rooms: :mod:`experiments.studies` (the entry points, one per ``conf/experiment/*.yaml``), :mod:`experiments.steps`
(what several share), :mod:`experiments.reports` (figures and markdown), :mod:`experiments.runs` (run folders) and
:mod:`experiments.schemas` (the typed settings); beside them :mod:`experiments.run` (the command),
:mod:`experiments.sweep` (a ``-m`` sweep's checks and signals) and :mod:`experiments.ros_node` (the live ROS 2 node).

The package's configs ship inside it (``experiments/conf``, the repository's ``conf/``). Importing the
package imports nothing heavy: Hydra and OmegaConf load when a name below is first used. See
``docs/architecture.md`` for the layout and the shared steps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hbni_infra.version import __version__

if TYPE_CHECKING:
    from experiments.runs.artifacts import Run, latest_run, load_run

__all__ = ["Run", "__version__", "latest_run", "load_run"]


def __getattr__(name: str) -> Any:
    if name in ("Run", "latest_run", "load_run"):
        from experiments.runs import artifacts

        return getattr(artifacts, name)
    raise AttributeError(f"module 'experiments' has no attribute {name!r}")
