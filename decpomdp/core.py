"""The Dec-POSMDP interface: agents run macro-actions (MAs) of random duration.

Time convention (shared by every domain and the simulator):

* Time is float64 and starts at 0. An MA started at ``t`` completes at ``end_time > t``.
* :meth:`DecPOSMDP.complete` returns the reward *earned at the completion time* ``t``; the
  simulator scales it by ``gamma ** t``.
* The simulation stops at ``horizon``: a completion at ``t <= horizon`` is processed (reward,
  observation, next MA); the first completion at ``t > horizon`` ends the rollout and earns nothing.
* Tabular Dec-POMDPs (:mod:`decpomdp.dpomdp`) use unit-duration MAs: the step-``k`` action starts at
  ``k`` and completes at ``k + 1``, so horizon ``h`` processes exactly ``h`` steps. Their ``complete``
  returns ``R / gamma`` so that step ``k``'s reward carries ``gamma ** k``, the Dec-POMDP convention
  (with ``gamma = 1`` the value is the standard finite-horizon value).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor


class DecPOSMDP:
    """A decentralised partially observable semi-Markov decision process.

    A domain gives its rules in one of two forms (or both): for the compiled engine, as
    :meth:`engine_model` (see :mod:`decpomdp.engine` and ``docs/engine.md``), or as batched torch
    methods :meth:`reset`, :meth:`start` and :meth:`complete` over a batch of rollouts (the torch
    simulator, ``backend="torch"``). The shipped domains give both: the torch methods are the engine's
    test oracle.

    Attributes:
        num_agents: A, the number of agents.
        num_actions: macro-actions per agent (the same set for every agent).
        num_obs: macro-observations per agent.
        gamma: discount per unit time; reward earned at time ``t`` is scaled by ``gamma ** t``.
        horizon: the simulation stops at this time (see the module docstring).
        action_names, obs_names: human-readable labels (length ``num_actions`` / ``num_obs``).
        counters: names of per-rollout counters (long (B,) entries of the state that change only in
            :meth:`complete`, e.g. deliveries), reported by :func:`decpomdp.domains.rollout_counters`.
    """

    counters: tuple[str, ...] = ()
    num_agents: int
    num_actions: int
    num_obs: int
    gamma: float
    horizon: float
    action_names: list[str]
    obs_names: list[str]

    def engine_model(self) -> Any:
        """This domain for the compiled engine (a :class:`decpomdp.engine.EngineModel`), or ``None``."""
        return None

    def reset(self, batch: int, generator: torch.Generator) -> dict[str, Tensor]:
        """Initial state of ``batch`` rollouts: a dict of tensors, batch dimension first."""
        raise self._no_torch_rules()

    def start(
        self,
        state: dict[str, Tensor],
        agents: Tensor,
        actions: Tensor,
        t: Tensor,
        end_time: Tensor,
        generator: torch.Generator,
    ) -> Tensor:
        """Flagged agents begin MA ``actions`` at time ``t``.

        Args:
            state: the batch state (may be mutated in place).
            agents: bool (B, A), the agents starting a new MA.
            actions: long (B, A), each agent's current MA (only flagged entries are new).
            t: float64 (B,), the current time of each rollout.
            end_time: float64 (B, A), the current completion times.

        Returns:
            float64 (B, A), the completion time of every agent: flagged agents get ``t + duration``;
            a domain may also move an unflagged agent's end time (e.g. joint MAs).
        """
        raise self._no_torch_rules()

    def complete(
        self,
        state: dict[str, Tensor],
        agents: Tensor,
        actions: Tensor,
        t: Tensor,
        generator: torch.Generator,
    ) -> tuple[Tensor, Tensor]:
        """Flagged agents finish MA ``actions`` at time ``t``.

        Args:
            agents: bool (B, A), the agents completing now (several may complete at once; a
                rollout may have no flagged agent, then nothing must change).

        Returns:
            reward: float64 (B,), undiscounted reward earned at ``t``.
            obs: long (B, A), each agent's macro-observation (only flagged entries are used).
        """
        raise self._no_torch_rules()

    def _no_torch_rules(self) -> NotImplementedError:
        return NotImplementedError(
            f"{type(self).__name__} is written for the compiled engine only: the torch "
            "simulator (backend='torch') needs reset, start and complete"
        )
