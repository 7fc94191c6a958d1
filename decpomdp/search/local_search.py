"""One local-search step on the incumbent controller: grow if needed, race the neighbourhood, duel.

1. Count the incumbent's edge traversals on ``visit_rollouts`` rollouts.
2. If some agent has fewer free (never visited) nodes than ``max_chain`` and the graph has fewer than
   ``max_nodes`` nodes, add ``grow_nodes`` unreachable nodes (up to ``max_nodes``).
3. Build the :class:`~decpomdp.search.moves.Neighbourhood`; if it has more than ``candidates`` moves,
   take every single edit and sample chains up to ``candidates`` (with replacement; sites in proportion
   to how often their edge is traversed, see :meth:`~decpomdp.search.moves.Neighbourhood.sample_chains`).
4. Race them through ``stages``. With ``compose``, the survivors' changes are also merged into one
   composite move, best survivor first, skipping any survivor that changes an entry already changed
   (independent improvements, such as routing two observations into a new chain, then land in one
   step).
5. Duel the survivors (and the composite) against the incumbent on ``duel_rollouts`` fresh rollouts;
   the best replaces the incumbent if it wins by more than ``z`` standard errors. Under exact scores a
   step therefore never returns a worse controller.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from decpomdp.controller import JointController
from decpomdp.search.moves import Neighbourhood, make_room
from decpomdp.search.racing import duel, race
from decpomdp.search.scoring import Scorer


@dataclass
class StepOutcome:
    """What a local-search step did.

    Attributes:
        controller: the incumbent after the step (grown, and replaced if a challenger won).
        accepted: whether a challenger replaced the incumbent.
        incumbent_value, challenger_value: duel means of the incumbent and of the best challenger.
        candidates: moves raced; neighbourhood: moves in the whole neighbourhood.
    """

    controller: JointController
    accepted: bool
    incumbent_value: float
    challenger_value: float
    candidates: int
    neighbourhood: int


def step(
    incumbent: JointController,
    scorer: Scorer,
    generator: torch.Generator,
    *,
    max_chain: int,
    max_nodes: int,
    grow_nodes: int,
    candidates: int,
    stages: Sequence[tuple[int, float]],
    duel_rollouts: int,
    z: float,
    edge_rate: float,
    visit_rollouts: int,
    team: bool = True,
    compose: bool = True,
    copy: bool = False,
    common: bool = False,
) -> StepOutcome:
    """One step (see the module doc)."""
    visits = scorer.visits(incumbent, visit_rollouts, generator)
    incumbent, visits = make_room(incumbent, visits, max_chain, max_nodes, grow_nodes)
    hood = Neighbourhood(incumbent, visits, scorer.num_actions, max_chain, edge_rate, team, copy)
    if hood.size == 0:
        return StepOutcome(incumbent, False, float("nan"), float("nan"), 0, 0)
    if hood.size <= candidates:
        index = torch.arange(hood.size)
    else:
        index = torch.cat(
            [torch.arange(hood.num_singles), hood.sample_chains(candidates - hood.num_singles, generator)]
        )
    alive, _, _ = race(scorer, index.numel(), lambda i: hood.build(index[i]), stages, generator, common=common)
    challengers = hood.build(index[alive])
    merged = composite(incumbent, challengers) if compose else None
    if merged is not None:
        challengers = JointController.cat([challengers, merged])
    winner, mean, _ = duel(scorer, incumbent, challengers, duel_rollouts, z, generator, common)
    best = int(mean[1:].argmax())
    controller = incumbent if winner is None else challengers[winner]
    return StepOutcome(controller, winner is not None, float(mean[0]), float(mean[1 + best]), index.numel(), hood.size)


def composite(incumbent: JointController, moves: JointController) -> JointController | None:
    """The changes of ``moves`` (K >= 1, best first) merged onto ``incumbent``, skipping any move that changes an
    entry an earlier one changed; None when fewer than two moves merge."""
    act0, nxt0 = incumbent.action[0], incumbent.next_node[0]
    act, nxt = act0.clone(), nxt0.clone()
    taken_act, taken_nxt = torch.zeros_like(act0, dtype=torch.bool), torch.zeros_like(nxt0, dtype=torch.bool)
    merged = 0
    for k in range(moves.num_controllers):
        d_act, d_nxt = moves.action[k] != act0, moves.next_node[k] != nxt0
        if bool((d_act & taken_act).any() or (d_nxt & taken_nxt).any()):
            continue
        act[d_act], nxt[d_nxt] = moves.action[k][d_act], moves.next_node[k][d_nxt]
        taken_act |= d_act
        taken_nxt |= d_nxt
        merged += 1
    return JointController(act[None], nxt[None]) if merged > 1 else None
