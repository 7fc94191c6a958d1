"""Run :func:`decpomdp.simulate` and also return each rollout's final per-rollout counters."""

from __future__ import annotations

import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from decpomdp.simulate import simulate

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
    env: DecPOSMDP, controller: JointController, rollouts: int, generator: torch.Generator, keys: tuple[str, ...] | None = None
) -> tuple[Tensor, dict[str, Tensor]]:
    """Discounted returns (K, R) and each counter's final value per rollout, {key: (K, R)}.

    Args:
        env: a domain whose counters (``env``'s module ``COUNTERS`` by default) change only in
            ``complete``, so the value after a rollout's last completion is final.
        keys: the state entries to report (long (B,) each).
    """
    if keys is None:
        keys = tuple(getattr(__import__(type(env).__module__, fromlist=["COUNTERS"]), "COUNTERS", ()))
    recorder = _Recorder(env, tuple(keys))
    returns = simulate(recorder, controller, rollouts, generator)
    shape = returns.shape
    return returns, {key: value.view(shape) for key, value in recorder.final.items()}
