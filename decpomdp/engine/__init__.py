"""The compiled rollout engine: one plain event loop per rollout, compiled with numba, parallel over rollouts.

* :mod:`.random`: counter-based random streams, one per rollout, keyed by (seed, controller, rollout);
* :mod:`.perception`: perception as a finite law of ``(label, frames)`` outcomes per true class;
* :mod:`.domain`: what a domain hands the engine (:class:`EngineDomain`, :class:`EngineModel`);
* :mod:`.loop`: the compiled event loop; :mod:`.simulate`: :func:`run`, its Python entry.

A domain is written once for the engine, as three small scalar rules (``reset``, ``start``,
``complete``); ``docs/engine.md`` shows a small domain written this way.
"""

from decpomdp.engine.domain import EngineDomain, EngineModel, StateLayout
from decpomdp.engine.perception import OutcomeTable, no_perception, outcome_table, sample_outcome
from decpomdp.engine.random import below, draw_seed, normal, uniform
from decpomdp.engine.simulate import EngineRun, engine_model, run

__all__ = [
    "EngineDomain", "EngineModel", "EngineRun", "OutcomeTable", "StateLayout", "below", "draw_seed", "engine_model",
    "no_perception", "normal", "outcome_table", "run", "sample_outcome", "uniform",
]
