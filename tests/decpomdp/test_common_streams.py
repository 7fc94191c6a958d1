"""Common random numbers: the engine's shared streams, racing stages and duels on them, and the planner's use."""

import pytest
import torch

from decpomdp import JointController
from decpomdp.domains import DisasterRelief, PackageDelivery
from decpomdp.domains import disaster_relief as dr
from decpomdp.engine import run
from decpomdp.search import PlannerConfig, RolloutScorer, gdice_config, plan
from decpomdp.search.moves import grow
from decpomdp.search.racing import duel, race
from hbni_infra.threads import threads
from planner_settings import short


def _alike(controller: JointController) -> JointController:
    """``controller``, a copy, and a copy with two nodes nobody reaches (the same behaviour)."""
    extra = grow(controller, 2)
    extra.action[0, :, -1] = 3  # an unreachable node's MA: changes nothing
    pad = grow(controller, 2)
    return JointController(
        torch.cat([pad.action, pad.action, extra.action]), torch.cat([pad.next_node, pad.next_node, extra.next_node])
    )


def _worse(controller: JointController) -> JointController:
    """The greedy ``controller`` with robot 0's edge out of node 7 on observation 0 moved: a different behaviour in
    some rollouts (about 0.1 less value)."""
    next_node = controller.next_node.clone()
    next_node[0, 0, 7, 0] = (next_node[0, 0, 7, 0] + 1) % controller.num_nodes
    return JointController(controller.action.clone(), next_node)


def test_common_streams_give_controllers_that_act_alike_the_same_returns():
    env, ctrl = DisasterRelief(), _alike(dr.greedy_controller())
    common = run(env, ctrl, 300, 5, common_streams=True).returns
    own = run(env, ctrl, 300, 5).returns
    assert torch.equal(common[0], common[1]) and torch.equal(common[0], common[2])
    assert not torch.equal(own[0], own[1])
    assert torch.equal(common[0], own[0])  # controller 0 keeps its own streams
    with threads(2):  # the thread count and the first controller's key leave the streams alone
        assert torch.equal(run(env, ctrl[1:], 300, 5, common_streams=True).returns[0], common[0])
    moved = run(env, ctrl, 300, 5, first_controller=4, common_streams=True).returns
    assert torch.equal(moved[0], run(env, ctrl, 300, 5, first_controller=4).returns[0])


def test_a_racing_stage_scores_every_batch_on_the_same_streams():
    scorer = RolloutScorer(DisasterRelief())
    ctrl = dr.greedy_controller()
    build = lambda i: JointController(ctrl.action.expand(len(i), -1, -1), ctrl.next_node.expand(len(i), -1, -1, -1))  # noqa: E731
    stages = [(20_000, 12)]  # 10 candidates per batched call: two calls
    _, common, _ = race(scorer, 12, build, stages, torch.Generator().manual_seed(0), common=True)
    _, own, _ = race(scorer, 12, build, stages, torch.Generator().manual_seed(0))
    assert torch.equal(common, common[:1].expand(12)) and own.unique().numel() > 1
    again = race(scorer, 12, build, stages, torch.Generator().manual_seed(0), common=True)[1]
    assert torch.equal(common, again)


def test_a_duel_on_common_streams_judges_the_differences():
    scorer = RolloutScorer(DisasterRelief())
    greedy = dr.greedy_controller()
    alike = _alike(greedy)
    winner, mean, _ = duel(scorer, alike[0], alike[1:], 400, 2.0, torch.Generator().manual_seed(1), common=True)
    assert winner is None and torch.equal(mean, mean[:1].expand(3))  # no noise where they act alike
    # a different controller: the paired standard error of the difference is below the unpaired one
    pool = JointController.cat([greedy, _worse(greedy)])
    returns = scorer.returns(pool, 4000, torch.Generator().manual_seed(2), common=True)
    paired = float((returns[1] - returns[0]).std() / 4000**0.5)
    unpaired = float(((returns[0].var() + returns[1].var()) / 4000) ** 0.5)
    assert float((returns[1] - returns[0]).abs().sum()) > 0 and paired < 0.5 * unpaired
    winner, _, _ = duel(scorer, _worse(greedy), greedy, 4000, 2.0, torch.Generator().manual_seed(3), common=True)
    assert winner == 0  # the better controller wins


def test_common_streams_need_the_engine_and_the_planner_falls_back_without_it():
    torch_scorer = RolloutScorer(PackageDelivery(), backend="torch")
    assert not torch_scorer.common_streams and RolloutScorer(PackageDelivery()).common_streams
    with pytest.raises(ValueError, match="common: common random numbers need the compiled engine"):
        torch_scorer.returns(_one_node(), 4, torch.Generator(), common=True)
    assert not gdice_config().common_streams and PlannerConfig().common_streams


def _one_node() -> JointController:
    return JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 13, dtype=torch.long))


def _config(**changes) -> PlannerConfig:
    """:data:`planner_settings.SHORT` with a larger budget on smaller phases, and ``changes``."""
    return short(
        budget=300_000,
        start_nodes=3,
        ce_iterations=2,
        ce_samples=40,
        ls_candidates=200,
        ls_stages=((8, 0.1), (64, 3)),
        ls_patience=1,
        duel_rollouts=400,
        **changes,
    )


def test_planning_on_common_streams_is_seeded_and_resumes_exactly(tmp_path):
    env = DisasterRelief()
    a = plan(RolloutScorer(env), _config(), seed=4, progress=False)
    b = plan(RolloutScorer(env), _config(), seed=4, progress=False)
    assert a.history == b.history and torch.equal(a.best.action, b.best.action)
    own = plan(RolloutScorer(env), _config(common_streams=False), seed=4, progress=False)
    assert own.history != a.history
    ckpt = tmp_path / "plan.safetensors"
    with pytest.raises(KeyboardInterrupt):
        plan(Interrupted(env, after=12), _config(), seed=4, checkpoint=ckpt, progress=False)
    assert ckpt.exists()
    resumed = plan(Interrupted(env, after=10**9), _config(), seed=4, checkpoint=ckpt, progress=False)
    assert resumed.history == a.history and torch.equal(resumed.best.next_node, a.best.next_node)


class Interrupted(RolloutScorer):
    """Stops the run (as Ctrl-C would) at its ``after``-th batch of rollouts."""

    def __init__(self, env, after: int) -> None:
        super().__init__(env)
        self.left = after

    def returns(self, controller, rollouts, generator, common=False):
        self.left -= 1
        if self.left < 0:
            raise KeyboardInterrupt
        return super().returns(controller, rollouts, generator, common)
