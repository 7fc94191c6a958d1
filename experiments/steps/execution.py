"""The mission's stage 6: every planned policy executed in closed loop on held-out recorded streams.

:func:`execute_closed_loop` runs each saved controller in the domain with every "infer" MA answered by its
variant's process on a fresh held-out stream of the true class (:mod:`experiments.steps.closed_loop`): the bank's;
a generative table's policy also the characterisation sequences'; a policy of ``mission.bank.powered``, when its
value test lacks power, also the bank's next sequences, rendered only as far as its process reads them
(:mod:`experiments.steps.on_demand`). Each entry gets the executed value, its stream standard errors, the
distribution check of its table and the value test (:mod:`experiments.steps.honesty`).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any, NamedTuple

import matplotlib.pyplot as plt
import torch
from tqdm.auto import tqdm

import hbni_pyro
from decpomdp import JointController
from experiments.reports import mission_report
from experiments.runs.clock import StageClock
from experiments.schemas.mission_study import MISSION_VARIANTS, Mission
from experiments.steps import closed_loop, honesty
from experiments.steps.on_demand import OnDemandStreams
from hbni_infra.streams import stream_seed


def entry_planning(settings: Mission, name: str) -> str:
    """The planning model of policy ``name`` (``exact`` for perfect perception)."""
    if name == "perfect":
        return "exact"
    return settings.mission.planning_model if name in MISSION_VARIANTS else name.rsplit("_", 1)[1]


def _entry_variant(name: str) -> str:
    """The perception variant of a planned policy: ``hbni_generative`` -> ``hbni``."""
    return name if name in MISSION_VARIANTS else name.rsplit("_", 1)[0]


def execute_closed_loop(
    bank: torch.Tensor,
    held: torch.Tensor,
    processes: dict[str, hbni_pyro.MacroObservationProcess],
    models: dict[str, hbni_pyro.MacroObservationModel],
    results: dict[str, dict],
    settings: Mission,
    clock: StageClock,
    run_dir: Path,
    more: OnDemandStreams,
) -> plt.Figure | None:
    """Stage 6: each saved controller executed with its variant's actual process on fresh held-out streams
    (perfect perception: in its own domain again); adds ``executed`` to every result entry, with the stream
    standard errors of the planned value (an empirical table of ``held``'s size) and of the executed one, by
    bootstrap from the pooled held-out and bank sequences, the distribution check of the entry's table against
    its process on those streams and the value test.

    A policy planned on an empirical table runs on the bank alone (its table was tabulated on ``held``); one
    planned on a simulated table saw no recorded sequence, so it runs on ``held`` and the bank together, which
    makes its value test more powerful at no cost. An entry of ``mission.bank.powered`` whose value test has
    less than its target power is executed again on more held-out sequences, rendered by ``more``
    (:func:`_powered`). Returns the reliability diagram of every process on the bank (``None`` without
    variants)."""
    clock.start("closed_loop", "6/6 executing every policy in closed loop on the held-out bank")
    pooled = torch.cat([held.double(), bank.double()], dim=1)  # (C, held + bank sequences, F, C)
    on_pool = {  # each variant's replay of every pooled stream (each run once)
        name: hbni_pyro.StreamReplay(p, *closed_loop.as_streams(pooled)) for name, p in processes.items()
    }
    loop = _Loop(held.shape[1], models, results, settings, clock)
    for name in tqdm(list(results), desc="closed loop", disable=not settings.progress):
        controller = JointController.load(run_dir / f"controller_{name}.safetensors")
        if name == "perfect":
            seed = stream_seed(settings.seed, "execute", name)
            executed = closed_loop.execute(controller, None, settings.domain, settings.study.reeval_rollouts, seed)
            results[name]["executed"] = closed_loop.summarise(results[name], executed, None)
            continue
        variant = _entry_variant(name)
        entry = _executed(name, controller, on_pool[variant], loop)
        if name in settings.mission.bank.powered.entries:
            entry = _powered(name, controller, entry, on_pool, processes[variant], more, loop)
        results[name]["executed"] = entry
    for name, replay in on_pool.items():
        results[name]["held_out_process"] = closed_loop.held_out_summary(replay, settings.mission.threshold)
    return (
        honesty.reliability_figure(
            processes, *closed_loop.as_streams(bank), mission_report.LABELS, settings.mission.threshold
        )
        if processes
        else None
    )


class _Loop(NamedTuple):
    """What every closed-loop entry reads: the characterisation sequences per class, the planning models, the
    planned results, the settings and the stage clock."""

    held: int
    models: dict[str, hbni_pyro.MacroObservationModel]
    results: dict[str, dict]
    settings: Mission
    clock: StageClock


def _powered(
    name: str,
    controller: JointController,
    entry: dict[str, Any],
    on_pool: dict[str, hbni_pyro.StreamReplay],
    process: hbni_pyro.MacroObservationProcess,
    more: OnDemandStreams,
    loop: _Loop,
) -> dict[str, Any]:
    """Policy ``name``'s closed-loop ``entry``, executed again on more held-out sequences while its value test has
    less than the target power: each step adds the bank's next sequences, rendered by ``more`` only as far as the
    process reads them, up to ``margin`` times what the power calculation asks for but at most doubling the
    sequences (the calculation rests on a noisy estimate of the streams' variance), never past
    ``max_sequences`` per class. Updates the variant's entry in ``on_pool``."""
    held, settings = loop.held, loop.settings
    powered, variant = settings.mission.bank.powered, _entry_variant(name)
    first = held if entry_planning(settings, name) == "empirical" else 0
    added, rendered = 0, []
    while entry["value_test"]["power"] < honesty.TARGET_POWER:
        have = int(on_pool[variant].streams_per_class[0])
        want = first + math.ceil(powered.margin * min(entry["value_test"]["sequences_for_target"], 1e9))
        count = min(want, 2 * have, powered.max_sequences) - have
        if count <= 0:
            break
        loop.clock.say(
            f"{name}: value test power {entry['value_test']['power']:.2f} on {have - first} held-out sequences "
            f"per class; rendering {count} more, each as far as its process reads it"
        )
        on_pool[variant], frames = more.replay(process, on_pool[variant], have - held, count)  # the bank's next
        added, rendered = added + count, rendered + [frames]
        entry = _executed(name, controller, on_pool[variant], loop)
    if added:
        frames = torch.cat(rendered, dim=1).double()
        entry["on_demand"] = {"sequences_per_class": added, "mean_frames_rendered": float(frames.mean())}
    return entry


def _executed(name: str, controller: JointController, pool: hbni_pyro.StreamReplay, loop: _Loop) -> dict[str, Any]:
    """The closed-loop entry of policy ``name`` on ``pool``, a replay of as many sequences of every class (in
    ``closed_loop.as_streams`` order), of which the first ``loop.held`` are the characterisation sequences (not
    fresh to an empirical table)."""
    held, models, results, settings, _ = loop
    C, per_class = pool.num_classes, int(pool.streams_per_class[0])
    seed = stream_seed(settings.seed, "execute", name)
    empirical = entry_planning(settings, name) == "empirical"
    first = held if empirical else 0
    fresh = per_class - first
    replay = closed_loop.resampled(pool, C, per_class, torch.arange(first, per_class))
    executed = closed_loop.execute(controller, replay, settings.domain, settings.study.reeval_rollouts, seed)
    resample = functools.partial(closed_loop.resampled, pool, C, per_class)
    boot = settings.mission.bootstrap
    on_bank = closed_loop.stream_stderr(
        controller,
        resample,
        per_class,
        fresh,
        settings.domain,
        boot,
        stream_seed(settings.seed, "bootstrap", "bank", name),
    )
    on_table = (
        0.0
        if not empirical
        else closed_loop.stream_stderr(
            controller,
            resample,
            per_class,
            held,
            settings.domain,
            boot,
            stream_seed(settings.seed, "bootstrap", "table", name),
        )
    )
    entry = closed_loop.summarise(results[name], executed, replay, on_table, on_bank)
    entry["sequences_per_class"] = fresh
    table_streams = held if empirical else settings.mission.generative_streams
    entry["distribution_check"] = honesty.distribution_test(
        models[name], replay, table_streams, stream_seed(settings.seed, "honesty", name)
    )
    entry["value_test"] = honesty.value_test(results[name], entry, fresh)
    return entry
