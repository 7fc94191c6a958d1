"""One robot's finite-state controller at run time: "MA done, I saw X: what now?".

A planned :class:`~decpomdp.controller.JointController` holds every robot's controller; on the
robot, a :class:`ControllerExecutor` runs one of them. It starts in node 0 and gives that node's
macro-action (MA); each time the MA completes, the robot passes the macro-observation it received
to :meth:`ControllerExecutor.observe`, which moves to ``next_node[node, obs]`` and returns the next
MA. This is exactly what the batched simulator (:mod:`decpomdp.simulate`) does for every agent of
every rollout; a test replays simulated observation sequences through executors and checks that
they choose the same MAs.

Observations are accepted as indices or as names (a domain's ``obs_names``); MAs come back as
:class:`MacroAction` ``(index, name)``. The state (node, number of observations) is inspectable
and serialisable as a JSON-able dict (:meth:`ControllerExecutor.state_dict`) that records a
fingerprint of the controller, so a state is never restored into another controller.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import Any, NamedTuple

import torch

from decpomdp.controller import JointController
from decpomdp.core import DecPOSMDP
from hbni_infra.fingerprint import check_fingerprint, digest

_STATE_KIND = "decpomdp.ControllerExecutor"


class MacroAction(NamedTuple):
    """An MA to run: its index in the domain's MA list and its name."""

    index: int
    name: str


def _index(value: Any, name: str, size: int) -> int:
    """``value`` as an int in ``[0, size)``: a Python or numpy integer, or a 0-d integer tensor."""
    if isinstance(value, torch.Tensor):
        if value.numel() != 1 or value.dim() > 1 or value.is_floating_point() or value.dtype == torch.bool:
            raise TypeError(
                f"{name}: expected an integer or a name, got a tensor of shape {tuple(value.shape)} "
                f"and dtype {value.dtype}"
            )
        value = int(value.item())
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name}: expected an integer index or a name, got {type(value).__name__}")
    if not 0 <= int(value) < size:
        raise ValueError(f"{name}: expected an index in [0, {size}), got {int(value)}")
    return int(value)


def _names(names: Sequence[str] | None, size: int, what: str, prefix: str) -> list[str]:
    if names is None:
        return [f"{prefix}{i}" for i in range(size)]
    names = list(names)
    if len(names) != size or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{what}: expected {size} strings, got {names!r}")
    if len(set(names)) != size:
        raise ValueError(f"{what}: names must be distinct, got {names!r}")
    return names


class ControllerExecutor:
    """Runs agent ``agent``'s finite-state controller of a one-controller :class:`JointController`.

    Args:
        controller: a loaded joint controller with K = 1 (select one with ``controller[k]``).
        agent: which robot's controller, in ``[0, A)``.
        action_names: MA names (``None``: the controller's, else ``"ma<i>"``); their number bounds the controller's
            actions. A named controller refuses other names (both lists in the message).
        obs_names: macro-observation names (``None``: the controller's, else ``"obs<i>"``: by index only).

    Use :meth:`for_domain` to take both name lists from a domain (and check the controller fits it).

    Attributes:
        node: the current node (0 at the start).
        steps: macro-observations received since the start.
        action: the current :class:`MacroAction`.
    """

    def __init__(
        self,
        controller: JointController,
        agent: int,
        action_names: Sequence[str] | None = None,
        obs_names: Sequence[str] | None = None,
    ) -> None:
        if not isinstance(controller, JointController):
            raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
        if controller.num_controllers != 1:
            raise ValueError(
                f"controller: expected one joint controller (K = 1), got K = {controller.num_controllers}; "
                "select one with controller[k]"
            )
        if action_names is None:
            action_names = controller.action_names
        if obs_names is None:
            obs_names = controller.obs_names
        self.agent = _index(agent, "agent", controller.num_agents)
        self._action = controller.action[0, self.agent].clone()  # (Nn,)
        self._next = controller.next_node[0, self.agent].clone()  # (Nn, O)
        top = int(self._action.max()) + 1
        self.action_names = _names(
            action_names, top if action_names is None else len(action_names), "action_names", "ma"
        )
        if top > len(self.action_names):
            raise ValueError(
                f"action_names: the controller uses MA {top - 1}, but only {len(self.action_names)} names are given"
            )
        self.obs_names = _names(obs_names, controller.num_obs, "obs_names", "obs")
        controller.check_names(self.action_names, self.obs_names, "the names given")
        self._obs_index = {n: i for i, n in enumerate(self.obs_names)}
        self._fingerprint = {"controller": digest(self._action, self._next), "agent": self.agent}
        self.node = 0
        self.steps = 0

    @classmethod
    def for_domain(cls, controller: JointController, agent: int, env: DecPOSMDP) -> ControllerExecutor:
        """An executor named after ``env``'s MAs and observations; the controller must fit ``env``."""
        if not isinstance(env, DecPOSMDP):
            raise TypeError(f"env: expected a DecPOSMDP, got {type(env).__name__}")
        if not isinstance(controller, JointController):
            raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
        if controller.num_obs != env.num_obs or controller.num_agents != env.num_agents:
            raise ValueError(
                f"controller: has {controller.num_agents} agents and {controller.num_obs} observations, "
                f"env has {env.num_agents} and {env.num_obs}"
            )
        controller.check_names(env.action_names, env.obs_names)
        return cls(controller, agent, env.action_names, env.obs_names)

    @property
    def num_nodes(self) -> int:
        return self._action.shape[0]

    @property
    def num_obs(self) -> int:
        return len(self.obs_names)

    @property
    def action(self) -> MacroAction:
        """The MA of the current node."""
        index = int(self._action[self.node])
        return MacroAction(index, self.action_names[index])

    def observe(self, observation: int | str | Any) -> MacroAction:
        """The current MA completed with ``observation`` (an index or a name): move on and return the next MA.

        Raises:
            TypeError: ``observation`` is neither an integer nor a string.
            ValueError: an index out of range or an unknown name.
        """
        self.node = int(self._next[self.node, self._observation(observation, "observation")])
        self.steps += 1
        return self.action

    def reachable(
        self, observations: Sequence[int | str], through: Sequence[str] | None = None
    ) -> dict[int, tuple[MacroAction, tuple[str, ...]]]:
        """The nodes the controller can reach from node 0 when each MA completes with one of ``observations``.

        Args:
            observations: the observations (indices or names) the MAs may complete with.
            through: the MAs that complete with them (names; ``None``: every MA). A node whose MA is not one of
                them is reached but not left: what it completes with is not among ``observations``.

        Returns:
            node -> (its MA, the observation names of the shortest way there), in the order found (node 0 first).
        """
        obs = [self._observation(o, "observations") for o in observations]
        found = {0: ()}
        todo = [0]
        while todo:
            node = todo.pop(0)
            if through is not None and self.action_names[int(self._action[node])] not in through:
                continue
            for o in obs:
                nxt = int(self._next[node, o])
                if nxt not in found:
                    found[nxt] = (*found[node], self.obs_names[o])
                    todo.append(nxt)
        return {
            node: (MacroAction(int(self._action[node]), self.action_names[int(self._action[node])]), path)
            for node, path in found.items()
        }

    def _observation(self, observation: int | str | Any, name: str) -> int:
        """The index of ``observation`` (an index or a name)."""
        if isinstance(observation, str):
            if observation not in self._obs_index:
                raise ValueError(f"{name}: unknown name {observation!r}; expected one of {self.obs_names}")
            return self._obs_index[observation]
        return _index(observation, name, self.num_obs)

    def reset(self) -> MacroAction:
        """Back to node 0 (a new mission); returns the first MA."""
        self.node, self.steps = 0, 0
        return self.action

    def state_dict(self) -> dict[str, Any]:
        """The run-time state as a JSON-able dict (with the fingerprint of the controller it belongs to)."""
        return {"kind": _STATE_KIND, "node": self.node, "steps": self.steps, "fingerprint": dict(self._fingerprint)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore a state written by :meth:`state_dict` of an executor of the same controller and agent.

        Raises:
            ValueError: not an executor state, written for another controller or agent (naming the
                field), or a node out of range.
        """
        if not isinstance(state, dict) or state.get("kind") != _STATE_KIND:
            raise ValueError(f"state: expected a dict written by ControllerExecutor.state_dict, got {state!r}")
        check_fingerprint(state.get("fingerprint"), self._fingerprint, "executor state")
        node = _index(state.get("node"), "state['node']", self.num_nodes)
        steps = state.get("steps")
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
            raise ValueError(f"state['steps']: expected an int >= 0, got {steps!r}")
        self.node, self.steps = node, steps

    def __repr__(self) -> str:
        return (
            f"ControllerExecutor(agent={self.agent}, node={self.node}/{self.num_nodes}, steps={self.steps}, "
            f"action={self.action.name!r})"
        )
