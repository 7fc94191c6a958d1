"""Writing a :class:`~decpomdp.dpomdp.DPOMDPModel` back to the MADP ``.dpomdp`` text format, and a controller
as text.

:func:`save_dpomdp` writes the header with the model's names (a count where the names are the indices
``0..n-1``), the start distribution as a vector, and one ``T``/``O``/``R`` line per stored nonzero with
joint actions and observations by index. Numbers are written with ``repr``, which reads back to the same
float64, so ``parse -> save -> parse`` gives the same model. The reward keeps its compact shape: an index
the reward does not depend on is written as ``*``.
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np

from decpomdp.controller import JointController
from decpomdp.dpomdp.model import DPOMDPModel
from hbni_infra.files import atomic_write_bytes


def _names(names: list[str]) -> str:
    return str(len(names)) if list(names) == [str(i) for i in range(len(names))] else " ".join(names)


def _num(x: float) -> str:
    return repr(float(x))


def dpomdp_text(model: DPOMDPModel) -> str:
    """The model as ``.dpomdp`` text."""
    if not isinstance(model, DPOMDPModel):
        raise TypeError(f"model: expected a DPOMDPModel, got {type(model).__name__}")
    lines = [
        f"agents: {_names(model.agent_names)}",
        f"discount: {_num(model.discount)}",
        "values: reward",
        f"states: {_names(model.state_names)}",
        "start:",
        " ".join(_num(p) for p in model.start),
        "actions:",
        *(_names(a) for a in model.action_names),
        "observations:",
        *(_names(o) for o in model.obs_names),
    ]
    t = model.transition
    n_s = t.num_states
    for row, s2, p in zip(t.rows().tolist(), t.indices.tolist(), t.data.tolist()):
        lines.append(f"T: {row // n_s} : {row % n_s} : {s2} : {_num(p)}")
    for ja, s2, jo in zip(*np.nonzero(model.observation)):
        lines.append(f"O: {ja} : {s2} : {jo} : {_num(model.observation[ja, s2, jo])}")
    r = model.reward
    for index in zip(*np.nonzero(r)):
        fields = " : ".join("*" if r.shape[k] == 1 else str(i) for k, i in enumerate(index))
        lines.append(f"R: {fields} : {_num(r[index])}")
    return "\n".join(lines) + "\n"


def save_dpomdp(model: DPOMDPModel, path: str | os.PathLike) -> Path:
    """Write ``model`` to ``path`` atomically (gzipped when the name ends in ``.gz``); returns the path."""
    path = Path(path)
    data = dpomdp_text(model).encode()
    atomic_write_bytes(path, gzip.compress(data, mtime=0) if path.suffix == ".gz" else data)
    return path


def controller_text(controller: JointController, index: int = 0) -> str:
    """Joint controller ``index`` as text, agent by agent: per node its action, then its successor after each
    observation (names where the controller carries them), one node per line; node 0 starts."""
    if not isinstance(controller, JointController):
        raise TypeError(f"controller: expected a JointController, got {type(controller).__name__}")
    action, nxt = controller.action[index], controller.next_node[index]
    act = controller.action_names or [str(a) for a in range(int(action.max()) + 1)]
    obs = controller.obs_names or [str(o) for o in range(nxt.shape[-1])]
    out = [
        f"# joint controller: {controller.num_agents} agents, {controller.num_nodes} nodes each; node 0 starts",
        "# node : action : next node after " + " ".join(obs),
    ]
    for agent in range(controller.num_agents):
        out.append(f"agent {agent}")
        for node in range(controller.num_nodes):
            succ = " ".join(str(int(n)) for n in nxt[agent, node])
            out.append(f"{node} : {act[int(action[agent, node])]} : {succ}")
    return "\n".join(out) + "\n"
