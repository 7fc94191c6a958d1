"""G-DICE as the planner's preset (:func:`decpomdp.search.gdice_config`): bit-for-bit the paper's algorithm
(the frozen reference ``gdice_reference.py``), improvement over random search, seeded determinism,
checkpoint/resume, warm starts, threshold rules, layered graphs and errors."""

import dataclasses
import math

import pytest
import torch

from decpomdp import JointController, monte_carlo_search
from decpomdp.domains import PackageDelivery
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value
from decpomdp.search import ExactScorer, RolloutScorer, gdice_config, plan
from decpomdp.search.cross_entropy import layered_mask

from gdice_reference import gdice as reference
from test_dpomdp_parser import BENCH
from test_planner import Interrupt
from tiny_problems import dec_tiger


@pytest.fixture(scope="module")
def recycling():
    return TabularDecPOSMDP.from_file(BENCH / "recycling.dpomdp", gamma=0.9)


def small(**overrides):
    return gdice_config(
        **({"num_nodes": 2, "start_nodes": 2, "ce_iterations": 3, "ce_samples": 10, "ce_elites": 2} | overrides)
    )


@pytest.mark.parametrize(
    "variant",
    [
        {},
        {"ce_threshold": "capped"},
        {"layer_width": 2, "num_nodes": 5, "start_nodes": 5},
        {"ce_injection_weight": 0.2},
    ],
)
def test_preset_reproduces_the_reference_exactly(variant):
    env = dec_tiger(3)
    cfg = gdice_config(
        **(
            {"ce_iterations": 12, "ce_samples": 30, "ce_elites": 5, "ce_alpha": 0.2, "num_nodes": 4, "start_nodes": 4}
            | variant
        )
    )
    res = plan(ExactScorer(env), cfg, seed=3)
    best, value, history = reference(
        lambda c, g: exact_value(env, c),
        env.num_agents,
        env.num_actions,
        env.num_obs,
        num_nodes=cfg.num_nodes,
        iterations=cfg.ce_iterations,
        samples=cfg.ce_samples,
        elites=cfg.ce_elites,
        alpha=cfg.ce_alpha,
        threshold_rule=cfg.ce_threshold,
        layer_width=cfg.layer_width,
        injection_weight=cfg.ce_injection_weight,
        seed=3,
    )
    assert res.value == value and math.isnan(res.stderr)  # a maximum over scores: no honest s.e.
    assert torch.equal(res.best.action, best.action) and torch.equal(res.best.next_node, best.next_node)
    assert res.history["best_sampled"] == history


def test_preset_reproduces_the_reference_on_rollouts():
    env = PackageDelivery()
    scorer = RolloutScorer(env, shared=True)
    res = plan(scorer, gdice_config(ce_iterations=4, ce_samples=16, ce_elites=4), seed=1)
    best, value, history = reference(
        lambda c, g: RolloutScorer(env, shared=True)(c, 80, g)[0],
        1,
        env.num_actions,
        env.num_obs,
        iterations=4,
        samples=16,
        elites=4,
        seed=1,
    )
    assert res.value == value and res.history["best_sampled"] == history
    assert torch.equal(res.best.action, best.action) and torch.equal(res.best.next_node, best.next_node)
    assert res.rollouts == scorer.rollouts_used == 4 * 16 * 80


def test_improves_over_random_search(recycling):
    cfg = small(ce_iterations=15, ce_samples=60, ce_elites=6, ce_alpha=0.2)
    res = plan(ExactScorer(recycling), cfg, seed=0)
    mcs = monte_carlo_search(ExactScorer(recycling), num_nodes=2, budget=15 * 60, rollouts=2, seed=0)
    # exact values: deterministic, no Monte Carlo error
    assert res.value == pytest.approx(exact_value(recycling, res.best).item())
    assert res.value > mcs.values.mean().item() + 5.0 and res.value >= mcs.best_value
    assert res.history["best_sampled"] == sorted(res.history["best_sampled"])  # best ever is monotone
    means = res.history["mean"]
    assert len(means) == 15 and means[-1] > means[0]  # the samples improve as the distributions concentrate


def test_seeded_determinism(recycling):
    cfg = small(num_nodes=3, start_nodes=3, ce_iterations=4, ce_samples=20, ce_elites=4)
    a, b = plan(ExactScorer(recycling), cfg, seed=5), plan(ExactScorer(recycling), cfg, seed=5)
    assert torch.equal(a.best.action, b.best.action) and a.history == b.history
    assert a.history != plan(ExactScorer(recycling), cfg, seed=6).history


@pytest.mark.parametrize("warm", [False, True])
def test_checkpoint_resume_equals_uninterrupted(tmp_path, toy_env, warm):
    env = toy_env(durations=(1.0, 2.0, 3.0), gamma=0.9, horizon=10.0, exponential=(0, 1), rate=1.0)
    cfg = small(
        num_nodes=3,
        start_nodes=3,
        ce_iterations=6,
        ce_samples=12,
        ce_elites=3,
        ce_alpha=0.2,
        ce_rollouts=8,
        ce_injection_weight=0.1,
        ce_injection_threshold=0.9,
        ce_threshold="capped" if warm else "paper",
        ce_init_weight=0.7 if warm else 0.0,
    )
    init = recycling_controller(2) if warm else None
    full = plan(RolloutScorer(env), cfg, seed=3, init=init)
    ckpt = tmp_path / "gdice.safetensors"
    with pytest.raises(KeyboardInterrupt):  # interrupted in its 5th iteration
        plan(Interrupt(RolloutScorer(env), 5), cfg, seed=3, init=init, checkpoint=ckpt, checkpoint_every=2)
    assert ckpt.exists()
    resumed = plan(Interrupt(RolloutScorer(env), 0), cfg, seed=3, init=init, checkpoint=ckpt, checkpoint_every=2)
    assert resumed.history == full.history and resumed.value == full.value
    assert torch.equal(resumed.best.next_node, full.best.next_node)
    for got, want in zip(resumed.distributions, full.distributions):
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    with pytest.raises(ValueError, match="another run: config.ce_iterations was 6 there, is 4 here"):
        plan(
            Interrupt(RolloutScorer(env), 0),
            dataclasses.replace(cfg, ce_iterations=4),
            seed=3,
            init=init,
            checkpoint=ckpt,
        )


def recycling_controller(num_nodes=2):
    """A fixed 2-agent recycling controller with ``num_nodes`` nodes (next node depends on node and obs)."""
    g = torch.Generator().manual_seed(11)
    return JointController(
        torch.randint(0, 3, (1, 2, num_nodes), generator=g),
        torch.randint(0, num_nodes, (1, 2, num_nodes, 2), generator=g),
    )


@pytest.mark.parametrize("init_nodes", [2, 3])
def test_warm_start_at_weight_one_samples_the_init_controller(recycling, init_nodes):
    init = recycling_controller(init_nodes)
    target = exact_value(recycling, init).item()
    res = plan(
        ExactScorer(recycling),
        small(num_nodes=3, start_nodes=3, ce_iterations=1, ce_samples=8, ce_init_weight=1.0),
        seed=0,
        init=init,
    )
    # every sample is ``init`` (the padding node is unreachable), so all of them score its exact value
    assert res.history["best_sampled"][0] == pytest.approx(target, abs=1e-9)
    assert res.history["mean"][0] == pytest.approx(target, abs=1e-9)
    assert torch.equal(res.best.action[..., :init_nodes], init.action)
    assert torch.equal(res.best.next_node[..., :init_nodes, :], init.next_node)
    assert res.distributions[0].shape == (2, 3, 3) and res.distributions[1].shape == (2, 3, 2, 3)


def test_warm_start_distributions(recycling):
    init, w = recycling_controller(2), 0.6
    res = plan(
        ExactScorer(recycling),
        small(num_nodes=3, start_nodes=3, ce_iterations=1, ce_samples=4, ce_elites=4, ce_alpha=1e-12, ce_init_weight=w),
        seed=0,
        init=init,
    )
    # alpha ~ 0: the final distributions are the initial ones up to 1e-12
    act = torch.full((2, 3, 3), (1 - w) / 3, dtype=torch.float64)
    act[:, :2] += w * torch.nn.functional.one_hot(init.action[0], 3).double()
    nxt = torch.full((2, 3, 2, 3), (1 - w) / 3, dtype=torch.float64)
    nxt[:, :2] += w * torch.nn.functional.one_hot(init.next_node[0], 3).double()
    act[:, 2], nxt[:, 2] = 1 / 3, 1 / 3  # the node the init controller lacks stays uniform
    torch.testing.assert_close(res.distributions[0], act, rtol=0, atol=1e-10)
    torch.testing.assert_close(res.distributions[1], nxt, rtol=0, atol=1e-10)


def test_warm_start_errors(recycling):
    scorer, init = ExactScorer(recycling), recycling_controller(2)
    with pytest.raises(ValueError, match="init: expected one controller"):
        plan(scorer, small(ce_init_weight=0.5), init=recycling_controller(3))  # more nodes than num_nodes
    with pytest.raises(ValueError, match="init: expected one controller"):
        plan(scorer, small(ce_init_weight=0.5), init=JointController.cat([init, init]))
    layered = small(num_nodes=3, start_nodes=3, layer_width=2, ce_init_weight=0.5)
    with pytest.raises(ValueError, match="layered"):
        plan(
            scorer,
            layered,
            init=JointController(torch.zeros(1, 2, 3, dtype=torch.long), torch.zeros(1, 2, 3, 2, dtype=torch.long)),
        )


class Scripted:
    """A scorer returning scripted values per call (sample j of call i scores ``values[i][j]``)."""

    num_agents, num_actions, num_obs, rollouts_used = 1, 2, 2, 0

    def __init__(self, values):
        self.values, self.calls = values, 0

    def __call__(self, ctrl, rollouts, generator):
        v = torch.tensor(self.values[self.calls], dtype=torch.float64)
        self.calls += 1
        return v, torch.zeros_like(v)

    def visits(self, ctrl, rollouts, generator):
        raise AssertionError("G-DICE does not count visits")


def test_threshold_rules():
    # iteration 0 is "lucky": its worst elite (9) is above everything iterations 1 and 2 sample
    values = [[10.0, 9.0, 1.0, 0.0], [5.0, 4.0, 3.0, 2.0], [8.0, 7.0, 6.0, 0.0]]
    cfg = small(ce_iterations=3, ce_samples=4, ce_elites=2)
    paper = plan(Scripted(values), cfg)
    assert paper.history["kept"] == [2.0, 0.0, 0.0] and paper.history["threshold"] == [9.0, 9.0, 9.0]
    capped = plan(Scripted(values), dataclasses.replace(cfg, ce_threshold="capped"))
    # capped at the current N_b-th best: 4 in iteration 1; in iteration 2 the rule (>= 4) admits 8 and 7 again
    assert capped.history["kept"] == [2.0, 2.0, 2.0] and capped.history["threshold"] == [9.0, 4.0, 7.0]
    # identical while the paper's rule admits N_b samples
    rising = [[1.0, 0.0, 0.0, 0.0], [2.0, 1.5, 0.0, 0.0], [3.0, 2.5, 2.0, 0.0]]
    a, b = plan(Scripted(rising), cfg), plan(Scripted(rising), dataclasses.replace(cfg, ce_threshold="capped"))
    assert a.history == b.history
    torch.testing.assert_close(a.distributions[1], b.distributions[1], rtol=0, atol=0)


def test_layered_graph_and_injection():
    mask = layered_mask(7, 3)
    assert mask[0].tolist() == [False, True, True, True, False, False, False]
    assert mask[1:4, 4:].all() and not mask[1:4, :4].any() and mask[4:, 4:].all() and not mask[4:, :4].any()
    env = dec_tiger(3)
    res = plan(
        ExactScorer(env),
        small(
            num_nodes=7,
            start_nodes=7,
            layer_width=3,
            ce_samples=50,
            ce_elites=5,
            ce_injection_weight=0.5,
            ce_injection_threshold=1.0,
            ce_injection_until=1.0,
        ),
        seed=0,
    )
    assert mask[torch.arange(7)[None, :, None].expand(2, 7, 2), res.best.next_node[0]].all()
    assert ((res.distributions[1] > 0) == mask[None, :, None, :]).all()  # injection stays inside the layers


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_nodes": 6, "start_nodes": 6, "layer_width": 2}, "layer_width"),
        ({"ce_threshold": "median"}, "ce_threshold"),
        ({"ce_result": "last"}, "ce_result"),
        ({"ce_init_weight": -0.1}, "ce_init_weight"),
        ({"ce_init_weight": 1.5}, "ce_init_weight"),
        ({"ce_injection_weight": 1.5}, "ce_injection_weight"),
        ({"ce_elites": 11, "ce_samples": 10}, "ce_elites"),
    ],
)
def test_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gdice_config(**kwargs)
