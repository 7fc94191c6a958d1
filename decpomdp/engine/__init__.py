"""The compiled rollout engine: one plain event loop per rollout, compiled with numba, parallel over rollouts.

* :mod:`hbni_infra.counter_random`: counter-based random streams, one per rollout, keyed by (seed, controller, rollout);
* :mod:`.outcomes`: perception as a finite law of ``(label, frames)`` outcomes per true class;
* :mod:`.interface`: what a domain hands the engine (:class:`EngineDomain`, :class:`EngineModel`);
* :mod:`.loop`: the compiled event loop; :mod:`.runner`: :func:`run`, its Python entry.

The compiled code is cached on disk (``CACHE_DIR``, :mod:`hbni_infra.numba_cache`, keyed by the sources it inlines).

A domain is written once for the engine, as three small scalar rules (``reset``, ``start``,
``complete``); ``docs/engine.md`` shows a small domain written this way.
"""

from hbni_infra.numba_cache import use_cache_dir

CACHE_DIR = use_cache_dir()  # before any engine function is decorated

from decpomdp.engine.interface import EngineDomain, EngineModel, StateLayout  # noqa: E402
from decpomdp.engine.outcomes import OutcomeTable, no_perception, outcome_table, sample_outcome  # noqa: E402
from hbni_infra.counter_random import below, draw_seed, normal, uniform  # noqa: E402
from decpomdp.engine.runner import EngineRun, engine_model, run  # noqa: E402

__all__ = [
    "EngineDomain",
    "EngineModel",
    "EngineRun",
    "OutcomeTable",
    "StateLayout",
    "below",
    "draw_seed",
    "engine_model",
    "no_perception",
    "normal",
    "outcome_table",
    "run",
    "sample_outcome",
    "uniform",
]
