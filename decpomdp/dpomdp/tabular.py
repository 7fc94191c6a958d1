"""A tabular Dec-POMDP as a Dec-POSMDP whose every primitive action is a unit-duration MA.

:func:`decpomdp.simulate` runs it on the compiled engine (:mod:`decpomdp.dpomdp.tabular_rules`); the batched
torch methods below are the engine's test oracle (``backend="torch"``).

Time convention (see :mod:`decpomdp.core`): the step-``k`` joint action starts at ``k`` and completes
at ``k + 1``; ``horizon = h`` runs ``h`` steps. ``complete`` samples ``s' ~ T(.|s, ja)`` from the sparse
row of ``(ja, s)``, ``jo ~ O(.|ja, s')`` and returns ``R(s, ja, s', jo) / gamma``, so with the
simulator's ``gamma ** (k+1)`` step ``k``'s reward is discounted by ``gamma ** k`` as in the
Dec-POMDP literature. Memory is that of the compact model: nothing is (JA, S, S') dense.

The torch methods run on the device of their generator (or index tensors): the sampling tables are
copied there once per device, and the CPU uses the tables themselves.
"""

from __future__ import annotations

import math
import os

import numpy as np
import torch
from torch import Tensor

from decpomdp.core import DecPOSMDP
from decpomdp.dpomdp import tabular_rules
from decpomdp.engine import EngineModel, no_perception
from decpomdp.dpomdp.model import DPOMDPModel
from decpomdp.dpomdp.parser import load_dpomdp
from decpomdp.dpomdp.problems import load_problem

_ROW_TOL = 1e-6


def _sample(cum: Tensor, generator: torch.Generator) -> Tensor:
    """One index per row of cumulative probabilities ``cum`` (B, n)."""
    u = torch.rand(cum.shape[0], 1, generator=generator, dtype=cum.dtype, device=cum.device) * cum[:, -1:]
    return torch.searchsorted(cum, u, right=True).squeeze(1).clamp_(max=cum.shape[1] - 1)


def _check_distributions(model: DPOMDPModel) -> None:
    sums = model.transition.row_sums()
    if np.abs(sums - 1.0).max(initial=0.0) > _ROW_TOL:
        ja, s = np.unravel_index(np.abs(sums - 1.0).argmax(), sums.shape)
        raise ValueError(f"model: transition row (joint action {ja}, state {s}) sums to {sums[ja, s]:.6g}, not 1")
    o_sums = model.observation.sum(-1)
    if np.abs(o_sums - 1.0).max(initial=0.0) > _ROW_TOL:
        ja, s = np.unravel_index(np.abs(o_sums - 1.0).argmax(), o_sums.shape)
        raise ValueError(f"model: observation row (joint action {ja}, state {s}) sums to {o_sums[ja, s]:.6g}, not 1")


class TabularDecPOSMDP(DecPOSMDP):
    """A ``.dpomdp`` model with unit-duration MAs.

    Args:
        model: a parsed :class:`~decpomdp.dpomdp.model.DPOMDPModel` (every agent with the same numbers
            of actions and observations; every T and O row a distribution).
        gamma: discount in (0, 1]; defaults to the file's.
        horizon: number of steps ``h`` (``math.inf`` for an infinite-horizon problem, which
            :func:`~decpomdp.dpomdp.exact.exact_value` evaluates but :func:`~decpomdp.simulate` cannot).

    Attributes (float64 torch tensors unless noted): ``start_dist`` (S,), ``observation`` (JA, S', JO),
    ``expected_reward`` (JA, S), and ``model`` (its sparse ``transition`` is what exact evaluation uses).
    """

    def __init__(self, model: DPOMDPModel, gamma: float | None = None, horizon: float = math.inf) -> None:
        if not isinstance(model, DPOMDPModel):
            raise TypeError(f"model: expected a DPOMDPModel, got {type(model).__name__}")
        n_act = {len(a) for a in model.action_names}
        n_obs = {len(o) for o in model.obs_names}
        if len(n_act) != 1 or len(n_obs) != 1:
            raise ValueError("model: every agent must have the same numbers of actions and of observations")
        _check_distributions(model)
        gamma = model.discount if gamma is None else float(gamma)
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"gamma: expected a discount in (0, 1], got {gamma}")
        if not (horizon == math.inf or (float(horizon).is_integer() and horizon >= 1)):
            raise ValueError(f"horizon: expected a whole number of steps >= 1 or math.inf, got {horizon}")
        if horizon == math.inf and gamma == 1.0:
            raise ValueError("horizon: an infinite horizon needs gamma < 1")
        self.model = model
        self.num_agents = model.num_agents
        self.num_actions, self.num_obs = n_act.pop(), n_obs.pop()
        self.num_states = model.num_states
        self.gamma, self.horizon = gamma, float(horizon)
        self.action_names = list(model.action_names[0])
        self.obs_names = list(model.obs_names[0])

        def f64(x):
            return torch.as_tensor(np.asarray(x, dtype=np.float64))

        self.start_dist = f64(model.start)
        self.observation = f64(model.observation)  # (JA, S', JO)
        self.expected_reward = f64(model.expected_reward())  # (JA, S)
        self._start_cum = self.start_dist.cumsum(0)
        self._o_cum = self.observation.cumsum(-1)
        t = model.transition
        self._t_indptr = torch.as_tensor(t.indptr)
        self._t_indices = torch.as_tensor(t.indices)
        self._t_cum = torch.as_tensor(np.cumsum(t.data))  # running sum over all stored entries, row after row
        self._t_cum0 = torch.cat([torch.zeros(1, dtype=torch.float64), self._t_cum])
        # the reward as a flat table with stride 0 along the indices it does not depend on
        r = np.ascontiguousarray(model.reward, dtype=np.float64)
        self._reward = torch.as_tensor(r.ravel())
        strides = np.cumprod((r.shape[1:] + (1,))[::-1])[::-1]
        self._reward_strides = [int(st) if n > 1 else 0 for st, n in zip(strides, r.shape)]
        a = self.num_agents
        self.action_strides = torch.tensor([self.num_actions ** (a - 1 - i) for i in range(a)])
        self.obs_strides = torch.tensor([self.num_obs ** (a - 1 - i) for i in range(a)])
        self._placed: dict[torch.device, dict[str, Tensor]] = {}

    def _on(self, device: torch.device) -> dict[str, Tensor]:
        """The sampling tables on ``device`` (the tables themselves on the CPU, copies made once elsewhere)."""
        names = (
            "_start_cum",
            "_o_cum",
            "_t_indptr",
            "_t_indices",
            "_t_cum",
            "_t_cum0",
            "_reward",
            "action_strides",
            "obs_strides",
        )
        if device.type == "cpu":
            return {n: getattr(self, n) for n in names}
        if device not in self._placed:
            self._placed[device] = {n: getattr(self, n).to(device) for n in names}
        return self._placed[device]

    @classmethod
    def from_file(
        cls, path: str | os.PathLike, gamma: float | None = None, horizon: float = math.inf
    ) -> TabularDecPOSMDP:
        """Load a ``.dpomdp`` or ``.dpomdp.gz`` file."""
        return cls(load_dpomdp(path), gamma, horizon)

    @classmethod
    def from_problem(cls, name: str, gamma: float | None = None, horizon: float = math.inf) -> TabularDecPOSMDP:
        """Load a problem shipped with the package (see :func:`~decpomdp.dpomdp.problem_path`)."""
        return cls(load_problem(name), gamma, horizon)

    def engine_model(self) -> EngineModel | None:
        """The problem for the compiled engine (:mod:`decpomdp.dpomdp.tabular_rules`); ``None`` for an infinite horizon."""
        if not math.isfinite(self.horizon):
            return None
        t = self.model.transition
        tab = tabular_rules.tables(
            self.start_dist.numpy(),
            t.indptr,
            t.indices,
            t.data,
            self._o_cum.numpy(),
            self._reward.numpy(),
            self._reward_strides,
            self.action_strides.numpy(),
            self.obs_strides.numpy(),
        )
        return EngineModel(tabular_rules.ENGINE, np.array([self.gamma]), tab, no_perception())

    def joint_action(self, actions: Tensor) -> Tensor:
        """(..., A) individual actions -> (...) joint index (first agent most significant)."""
        strides = self.action_strides if actions.device.type == "cpu" else self._on(actions.device)["action_strides"]
        return (actions * strides).sum(-1)

    def split_obs(self, jo: Tensor) -> Tensor:
        """(...) joint observation -> (..., A) individual observations."""
        strides = self.obs_strides if jo.device.type == "cpu" else self._on(jo.device)["obs_strides"]
        return (jo[..., None] // strides) % self.num_obs

    def sample_next_state(self, ja: Tensor, s: Tensor, generator: torch.Generator) -> Tensor:
        """``s' ~ T(. | s, ja)`` for (B,) joint actions and states, from the sparse rows."""
        tab = self._on(generator.device)
        row = ja * self.num_states + s
        lo, hi = tab["_t_indptr"][row], tab["_t_indptr"][row + 1]
        base, total = tab["_t_cum0"][lo], tab["_t_cum0"][hi] - tab["_t_cum0"][lo]
        target = base + torch.rand(row.shape, generator=generator, dtype=torch.float64, device=generator.device) * total
        idx = torch.searchsorted(tab["_t_cum"], target, right=True)
        return tab["_t_indices"][torch.minimum(torch.maximum(idx, lo), hi - 1)]

    def reward_of(self, ja: Tensor, s: Tensor, s2: Tensor, jo: Tensor) -> Tensor:
        """``R(ja, s, s', jo)`` for (B,) index tensors."""
        st = self._reward_strides
        return self._on(ja.device)["_reward"][ja * st[0] + s * st[1] + s2 * st[2] + jo * st[3]]

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        start_cum = self._on(generator.device)["_start_cum"]
        u = torch.rand(batch, generator=generator, dtype=torch.float64, device=generator.device) * start_cum[-1]
        return {"s": torch.searchsorted(start_cum, u, right=True).clamp_(max=self.num_states - 1)}

    def start(self, state, agents, actions, t, end_time, generator) -> Tensor:
        return torch.where(agents, t[:, None] + 1.0, end_time)

    def complete(self, state, agents, actions, t, generator) -> tuple[Tensor, Tensor]:
        act = agents.any(dim=1)
        s = state["s"]
        ja = self.joint_action(actions)
        s2 = self.sample_next_state(ja, s, generator)
        jo = _sample(self._on(generator.device)["_o_cum"][ja, s2], generator)
        reward = torch.where(act, self.reward_of(ja, s, s2, jo) / self.gamma, 0.0)
        state["s"] = torch.where(act, s2, s)
        return reward, self.split_obs(jo)
