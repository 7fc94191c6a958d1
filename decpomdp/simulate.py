"""Simulation of K joint controllers x R rollouts: the compiled engine, or the batched torch simulator.

:func:`simulate` runs a domain written for the compiled engine (:mod:`decpomdp.engine`: every shipped
domain, with any perception model that has an outcome table) there by default; ``backend="torch"``
selects the batched torch simulator below, which also runs any user-written
:class:`~decpomdp.core.DecPOSMDP` and is the test oracle of the engine.

The torch loop runs over *completion events*, not time steps or rollouts: every iteration advances
each live rollout to its next completion time ``t_next = min_a end_time``, lets every agent
completing at ``t_next`` collect reward and a macro-observation, moves those agents along their
controllers and starts their next MA. Rollouts whose next completion lies beyond the horizon
stop; once a quarter of the batch has stopped the live rollouts are compacted, so long tails
cost little. See :mod:`decpomdp.core` for the time convention. The torch simulator runs on the
device of its generator (every tensor is made there).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from decpomdp.batched import any_true, lookup
from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.engine import draw_seed, engine_model
from decpomdp.engine import run as run_engine
from hbni_infra.checks import as_generator, as_int

BACKENDS = ("engine", "torch")
#: The backend a call without one uses: ``None`` (or ``"engine"``) is the engine wherever the domain is written
#: for it; ``"torch"`` runs everything on the batched torch simulator (e.g. to check a result on the oracle).
DEFAULT_BACKEND: str | None = None


def check(env: DecPOSMDP, controller: JointController) -> None:
    """Raise unless ``controller`` fits ``env`` (agents, observations, actions, and the names of a named
    controller) and the horizon is finite."""
    if not isinstance(env, DecPOSMDP):
        raise TypeError(f"env: expected a DecPOSMDP, got {type(env).__name__}")
    if not isinstance(controller, JointController):
        raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
    if controller.num_agents != env.num_agents:
        raise ValueError(f"controller: has {controller.num_agents} agents, env has {env.num_agents}")
    if controller.num_obs != env.num_obs:
        raise ValueError(f"controller: has {controller.num_obs} observations, env has {env.num_obs}")
    controller.check_names(env.action_names, env.obs_names)
    # on the CPU, NumPy's single-threaded reduction: torch's wakes its intra-op threads, which then spin for
    # milliseconds beside the engine's workers (a two-thread batch of 8000 controllers ran 10 % slower)
    action = controller.action
    if int(action.numpy().max() if action.device.type == "cpu" else action.max()) >= env.num_actions:
        raise ValueError(f"controller: action entries must lie in [0, {env.num_actions})")
    if not math.isfinite(env.horizon):
        raise ValueError(f"env: simulation needs a finite horizon, got {env.horizon}")


def resolve_backend(env: DecPOSMDP, backend: str | None) -> str:
    """``backend``, or (``None``) :data:`DEFAULT_BACKEND`, or the engine when ``env`` is written for it and torch
    otherwise."""
    if backend is not None and backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS} or None, got {backend!r}")
    if backend == "torch" or (backend is None and DEFAULT_BACKEND == "torch"):
        return "torch"
    supported = engine_model(env) is not None
    if backend == "engine" and not supported:
        raise ValueError(
            f"backend: 'engine' needs a domain written for the compiled engine with a tabular perception "
            f"model; {type(env).__name__} is not (use backend='torch')"
        )
    return "engine" if supported else "torch"


def _flat_tables(controller: JointController, rollouts: int, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    """int32 flat ``action`` and ``next_node`` tables, and each rollout's offset into them.

    int32 because int64 elementwise ops cost several times more on CPU. The offset of rollout ``b``
    (of controller ``b // rollouts``) for agent ``a`` is where that controller's agent-``a`` rows
    start in the ``(K, A, Nn)`` table: (K * rollouts, A). All three live on ``device``.
    """
    k_count, a_count, n_nodes = controller.action.shape
    act_table = controller.action.reshape(-1).to(device, torch.int32)
    next_table = controller.next_node.reshape(-1).to(device, torch.int32)
    owner = torch.arange(k_count, device=device).repeat_interleave(rollouts)[:, None]
    base = ((owner * a_count + torch.arange(a_count, device=device)) * n_nodes).to(torch.int32)
    return act_table, next_table, base


def _rows(keep: Tensor, *tensors: Tensor) -> tuple[Tensor, ...]:
    """The rows ``keep`` of every tensor (compaction of the live rollouts)."""
    return tuple(x[keep] for x in tensors)


def simulate(
    env: DecPOSMDP,
    controller: JointController,
    rollouts_per_controller: int,
    generator: torch.Generator,
    backend: str | None = None,
) -> Tensor:
    """Discounted return of every rollout.

    Args:
        env: the Dec-POSMDP.
        controller: K joint controllers.
        rollouts_per_controller: R >= 1.
        generator: the only source of randomness, a ``torch.Generator`` (``None`` or a seed is a ``TypeError``: no
            call draws from torch's global stream); the engine draws one seed from it per call, the torch
            simulator runs on its device (a CUDA generator needs ``backend="torch"`` and a domain whose torch
            methods support it, e.g. :class:`~decpomdp.dpomdp.TabularDecPOSMDP`).
        backend: ``"engine"``, ``"torch"`` or ``None`` (the engine where ``env`` is written for it).

    Returns:
        float64 (K, R): return of rollout ``r`` of controller ``k`` (on the generator's device for the torch
        simulator, on the CPU for the engine).
    """
    check(env, controller)
    rollouts_per_controller = as_int("rollouts_per_controller", rollouts_per_controller, minimum=1)
    generator = as_generator("generator", generator)
    if resolve_backend(env, backend) == "engine":
        return run_engine(env, controller, rollouts_per_controller, draw_seed(generator)).returns
    return simulate_torch(env, controller, rollouts_per_controller, generator)


def simulate_torch(
    env: DecPOSMDP, controller: JointController, rollouts_per_controller: int, generator: torch.Generator
) -> Tensor:
    """:func:`simulate` on the batched torch simulator (arguments already checked), on ``generator.device``.

    The event loop stays in one function on purpose: its steps share a dozen live-row tensors that
    compaction replaces together, and splitting it would pass them all back and forth.
    """
    k_count, a_count = controller.num_controllers, controller.num_agents
    batch = k_count * rollouts_per_controller
    n_obs = controller.num_obs
    dev = generator.device
    act_table, next_table, base = _flat_tables(controller, rollouts_per_controller, dev)
    values = torch.zeros(batch, dtype=torch.float64, device=dev)
    rows = torch.arange(batch, device=dev)  # original index of each live row

    state = env.reset(batch, generator)
    node = torch.zeros(batch, a_count, dtype=torch.int32, device=dev)
    actions = lookup(act_table, base)
    t = torch.zeros(batch, dtype=torch.float64, device=dev)
    all_agents = torch.ones(batch, a_count, dtype=torch.bool, device=dev)
    end_time = env.start(
        state, all_agents, actions, t, torch.zeros(batch, a_count, dtype=torch.float64, device=dev), generator
    )
    log_gamma = math.log(float(env.gamma))
    horizon = float(env.horizon)
    value = torch.zeros(batch, dtype=torch.float64, device=dev)
    t_prev = t

    while rows.numel() > 0:
        t_next = torch.minimum(end_time[:, 0], end_time[:, 1]) if a_count == 2 else end_time.amin(dim=1)
        # every MA ends after the event that started it (inf - inf = nan on frozen rows compares False)
        if any_true(t_next - t_prev <= 0):
            raise RuntimeError("env.start returned a completion time not after the start time (zero duration)")
        live = t_next <= horizon
        some_dead = any_true(~live)
        if some_dead:
            values[rows[~live]] = value[~live]
            if int(live.sum()) * 4 <= rows.numel() * 3:
                keep = live.nonzero().squeeze(1)
                rows, base, value, node, actions, end_time, t_next, live = _rows(
                    keep, rows, base, value, node, actions, end_time, t_next, live
                )
                state = {key: v[keep] for key, v in state.items()}
                some_dead = False
                if rows.numel() == 0:
                    break
        completing = end_time == torch.stack([t_next] * a_count, dim=1)  # faster than broadcasting a (B, 1) operand
        discount = torch.exp(t_next * log_gamma)  # gamma ** t
        if some_dead:  # rows past the horizon neither complete nor earn
            live_pair = torch.stack([live] * a_count, dim=1)
            completing &= live_pair
            discount = torch.where(live, discount, 0.0)
        reward, obs = env.complete(state, completing, actions, t_next, generator)
        value.addcmul_(reward, discount)
        stepped = lookup(next_table, (base + node) * n_obs + obs.to(torch.int32).clamp_(0, n_obs - 1))
        node += completing.view(torch.uint8) * (stepped - node)
        actions = lookup(act_table, base + node)  # unchanged where the node did not move
        end_time = env.start(state, completing, actions, t_next, end_time, generator)
        if some_dead:  # rows that stopped but were not compacted stay frozen: they never complete again
            end_time = torch.where(live_pair, end_time, math.inf)
        t_prev = t_next
    return values.view(k_count, rollouts_per_controller)
