"""Running controllers on the domains: final per-rollout counters, and one controller shared by a team."""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.engine import draw_seed, engine_model
from decpomdp.engine import run as run_engine
from decpomdp.simulate import check, resolve_backend, simulate
from hbni_infra.checks import as_int

_ROW = "_rollout_row"


class _Recorder(DecPOSMDP):
    """Delegates to ``env`` and copies the counters of every rollout after each completion event."""

    def __init__(self, env: DecPOSMDP, keys: tuple[str, ...]) -> None:
        self.env, self.keys = env, keys
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs
        self.gamma, self.horizon = env.gamma, env.horizon
        self.action_names, self.obs_names = env.action_names, env.obs_names
        self.final: dict[str, Tensor] = {}

    def reset(self, batch, generator):
        state = self.env.reset(batch, generator)
        missing = [key for key in self.keys if key not in state]
        if missing:
            raise ValueError(f"keys: {missing} are not in the state of {type(self.env).__name__}")
        state[_ROW] = torch.arange(batch)
        self.final = {key: state[key].clone() for key in self.keys}
        return state

    def start(self, state, agents, actions, t, end_time, generator):
        return self.env.start(state, agents, actions, t, end_time, generator)

    def complete(self, state, agents, actions, t, generator):
        reward, obs = self.env.complete(state, agents, actions, t, generator)
        for key in self.keys:
            self.final[key][state[_ROW]] = state[key]
        return reward, obs


def rollout_counters(
    env: DecPOSMDP,
    controller: JointController,
    rollouts: int,
    generator: torch.Generator,
    keys: tuple[str, ...] | None = None,
    backend: str | None = None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """Discounted returns (K, R) and each counter's final value per rollout, {key: (K, R)}.

    Args:
        env: a domain whose counters (``env.counters`` by default) change only in ``complete``, so the
            value after a rollout's last completion is final.
        keys: the state entries to report (long (B,) each).
        backend: as in :func:`~decpomdp.simulate.simulate` (the compiled engine where ``env`` is written for it).
    """
    if keys is None:
        keys = env.counters
    keys = tuple(keys)
    if resolve_backend(env, backend) == "engine":
        check(env, controller)
        rollouts = as_int("rollouts", rollouts, minimum=1)
        model = engine_model(env)
        missing = [key for key in keys if key not in model.domain.counters]
        if missing:
            raise ValueError(f"keys: {missing} are not counters of {type(env).__name__} {model.domain.counters}")
        result = run_engine(env, controller, rollouts, draw_seed(generator))
        return result.returns, {key: result.counters[key] for key in keys}
    recorder = _Recorder(env, keys)
    returns = simulate(recorder, controller, rollouts, generator, backend="torch")
    shape = returns.shape
    return returns, {key: value.view(shape) for key, value in recorder.final.items()}


def shared(controller: JointController, num_agents: int) -> JointController:
    """Give every agent the FSC of agent 0: a (K, 1, Nn) controller becomes (K, num_agents, Nn)."""
    if not isinstance(controller, JointController):
        raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
    num_agents = as_int("num_agents", num_agents, minimum=1)
    k, _, n = controller.action.shape
    o = controller.num_obs
    return JointController(
        controller.action[:, :1].expand(k, num_agents, n).contiguous(),
        controller.next_node[:, :1].expand(k, num_agents, n, o).contiguous(),
    )
