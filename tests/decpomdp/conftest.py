"""A tiny hand-written Dec-POSMDP whose returns can be computed by hand (shared by the core tests).

Two agents; MA ``a`` lasts ``durations[a]`` time units (deterministic) or, for an MA listed in
``exponential``, an Exp(rate) time. Completing MA ``a`` earns ``a + 1`` per agent. An agent observes 1
when the other agent completes at the same instant, else 0. MA 2 is a joint MA: an agent starting it
pulls its partner's completion time to its own when the partner is also running MA 2.
``state["count"]`` counts each agent's completions.
"""

from __future__ import annotations

import pytest
import torch

from decpomdp import DecPOSMDP


class ToyEnv(DecPOSMDP):
    def __init__(self, durations=(1.0, 2.0, 3.0), gamma=0.5, horizon=4.0, exponential=(), rate=1.0):
        self.num_agents, self.num_actions, self.num_obs = 2, 3, 2
        self.gamma, self.horizon = gamma, horizon
        self.durations = torch.tensor(durations, dtype=torch.float64)
        self.exponential = torch.zeros(3, dtype=torch.bool)
        self.exponential[list(exponential)] = True
        self.rate = rate
        self.action_names, self.obs_names = ["short", "long", "joint"], ["alone", "together"]

    def reset(self, batch, generator):
        return {"count": torch.zeros(batch, 2, dtype=torch.long)}

    def start(self, state, agents, actions, t, end_time, generator):
        u = torch.rand(actions.shape, generator=generator, dtype=torch.float64)
        dur = torch.where(self.exponential[actions], -torch.log1p(-u) / self.rate, self.durations[actions])
        end = torch.where(agents, t[:, None] + dur, end_time)
        joint = (actions == 2).all(dim=1) & agents.any(dim=1)
        sync = torch.where(agents, end, torch.full_like(end, -1.0)).max(dim=1).values
        return torch.where(joint[:, None], sync[:, None].expand_as(end), end)

    def complete(self, state, agents, actions, t, generator):
        state["count"] += agents.long()
        reward = ((actions + 1) * agents).sum(dim=1).to(torch.float64)
        both = agents.all(dim=1, keepdim=True)
        return reward, both.long().expand_as(actions).clone()


@pytest.fixture
def toy_env():
    """Factory for :class:`ToyEnv`."""
    return ToyEnv


@pytest.fixture(params=["engine", "torch"])
def backend(request, monkeypatch):
    """Run the test on the compiled engine and on the batched torch oracle (the default backend of every call)."""
    import importlib

    monkeypatch.setattr(importlib.import_module("decpomdp.simulate"), "DEFAULT_BACKEND", request.param)
    return request.param
