"""G-DICE: improvement over random search, seeded determinism, checkpoint/resume, warm start, threshold rules,
options and errors."""

import dataclasses
import math
import re

import numpy as np
import pytest
import torch

from decpomdp import GDICEConfig, JointController, MonteCarloEvaluator, gdice, monte_carlo_search, sample_controllers
from infra.tensorfile import load_tensors, save_tensors
from decpomdp.dpomdp import ExactEvaluator, TabularDecPOSMDP, exact_value
from decpomdp.identity import describe

from test_dpomdp_parser import BENCH
from tiny_problems import dec_tiger


@pytest.fixture(scope="module")
def recycling():
    return TabularDecPOSMDP.from_file(BENCH / "recycling.dpomdp", gamma=0.9)


def run(env, cfg, **kw):
    return gdice(ExactEvaluator(env), env.num_agents, env.num_actions, env.num_obs, cfg, **kw)


def test_improves_over_random(recycling):
    cfg = GDICEConfig(num_nodes=2, iterations=15, samples=60, elites=6, alpha=0.2)
    res = run(recycling, cfg, seed=0, reevaluator=ExactEvaluator(recycling))
    mcs = monte_carlo_search(ExactEvaluator(recycling), 2, 3, 2, num_nodes=2, budget=15 * 60, seed=0)
    # exact values: deterministic, no Monte Carlo error
    assert res.value == pytest.approx(exact_value(recycling, res.best).item()) == pytest.approx(res.best_value)
    assert res.best_value > mcs.values.mean().item() + 5.0
    assert res.best_value >= mcs.best_value
    assert res.history["best"] == sorted(res.history["best"])  # best ever is monotone
    assert len(res.history["iteration_mean"]) == 15 and res.stderr == 0.0
    # the mean sampled value rises as the distributions concentrate
    assert res.history["iteration_mean"][-1] > res.history["iteration_mean"][0]


def test_seeded_determinism(recycling):
    cfg = GDICEConfig(num_nodes=3, iterations=4, samples=20, elites=4)
    a, b = run(recycling, cfg, seed=5), run(recycling, cfg, seed=5)
    assert torch.equal(a.best.action, b.best.action) and a.history == b.history
    assert a.history != run(recycling, cfg, seed=6).history


@pytest.mark.parametrize("warm", [False, True])
def test_checkpoint_resume_equals_uninterrupted(tmp_path, toy_env, warm):
    env = toy_env(durations=(1.0, 2.0, 3.0), gamma=0.9, horizon=10.0, exponential=(0, 1), rate=1.0)
    cfg = GDICEConfig(num_nodes=3, iterations=6, samples=12, elites=3, alpha=0.2, injection_weight=0.1,
                      injection_threshold=0.9, threshold_rule="capped" if warm else "paper",
                      init_weight=0.7 if warm else 0.0)
    init = recycling_controller(2) if warm else None
    evaluator = MonteCarloEvaluator(env, 8)
    full = gdice(evaluator, 2, 3, 2, cfg, seed=3, init=init)
    ckpt = tmp_path / "gdice.safetensors"
    # interrupt the run in its 5th iteration; the last checkpoint holds iteration 4 and the generator state
    with pytest.raises(KeyboardInterrupt):
        gdice(Interrupted(evaluator, 5), 2, 3, 2, cfg, seed=3, init=init, checkpoint=ckpt, checkpoint_every=2)
    assert ckpt.exists()
    resumed = gdice(evaluator, 2, 3, 2, cfg, seed=3, init=init, checkpoint=ckpt, checkpoint_every=2)
    assert resumed.history == full.history
    assert torch.equal(resumed.best.next_node, full.best.next_node) and resumed.best_value == full.best_value
    torch.testing.assert_close(resumed.next_probs, full.next_probs, rtol=0, atol=0)
    with pytest.raises(ValueError, match="another run: config.iterations was 6 there, is 4 here"):
        gdice(evaluator, 2, 3, 2, dataclasses.replace(cfg, iterations=4), seed=3, init=init, checkpoint=ckpt)
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="is not a readable model file"):
        gdice(evaluator, 2, 3, 2, cfg, init=init, checkpoint=bad)


class Interrupted:
    """Delegates to ``evaluator`` (and describes itself as it) but raises KeyboardInterrupt on call ``at``."""

    def __init__(self, evaluator, at):
        self.evaluator, self.at, self.calls = evaluator, at, 0

    def fingerprint(self):
        return describe(self.evaluator)

    def __call__(self, ctrl, gen):
        self.calls += 1
        if self.calls == self.at:
            raise KeyboardInterrupt
        return self.evaluator(ctrl, gen)


LISTEN = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
OPEN = JointController(torch.ones(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))


def tiger_run(tmp_path, horizon=3, seed=0, **changes):
    """A Dec-Tiger G-DICE run with a checkpoint in ``tmp_path`` (exact values)."""
    env = dec_tiger(horizon)
    cfg = dataclasses.replace(GDICEConfig(num_nodes=2, iterations=2, samples=6, elites=2), **changes.pop("config", {}))
    sizes = changes.pop("sizes", (2, 3, 2))
    return gdice(ExactEvaluator(env), *sizes, cfg, seed=seed, checkpoint=tmp_path / "tiger.safetensors", **changes)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    # the reported case: a horizon-3, seed-0 checkpoint resumed by a horizon-4, seed-7 run
    first = tiger_run(tmp_path, horizon=3, seed=0)
    with pytest.raises(ValueError, match=r"another run: problem\.env\.horizon was 3\.0 there, is 4\.0 here"):
        tiger_run(tmp_path, horizon=4, seed=7)
    again = tiger_run(tmp_path, horizon=3, seed=0)  # the same run resumes (here: is already finished)
    assert again.history == first.history and again.best_value == first.best_value


@pytest.mark.parametrize("change, field", [
    ({"seed": 1}, "seed"),
    ({"horizon": 4}, "problem.env.horizon"),
    ({"config": {"alpha": 0.3}}, "config.alpha"),
    ({"config": {"num_nodes": 3}}, "config.num_nodes"),
    ({"sizes": (2, 3, 3)}, "sizes.num_obs"),
    ({"init": LISTEN}, "init"),
])
def test_checkpoint_names_each_differing_field(tmp_path, change, field):
    warm = {"config": {"init_weight": 0.5}}  # both runs warm-started, from different controllers
    tiger_run(tmp_path, **(warm | {"init": OPEN} if field == "init" else {}))
    if field == "init":
        change = change | warm
    with pytest.raises(ValueError, match=rf"another run: {re.escape(field)} was "):
        try:
            tiger_run(tmp_path, **change)
        except RuntimeError as exc:  # a wrong number of observations must not get as far as evaluating
            raise AssertionError(f"evaluated before checking the checkpoint: {exc}") from None


def rewrite_checkpoint(path, **meta_changes):
    tensors, meta = load_tensors(path, "decpomdp.GDICECheckpoint")
    meta.update(meta_changes)
    save_tensors(path, "decpomdp.GDICECheckpoint", tensors, meta)


@pytest.mark.parametrize("changes, match", [
    ({"history": None}, "history = NoneType, expected a dict"),
    ({"iteration": -1}, "iteration = -1, expected an int in \\[0, 2\\]"),
    ({"iteration": 7}, "iteration = 7"),
    ({"iteration": 1}, "history\\['best'\\] inconsistent with 1 recorded iterations"),
    ({"best_value": "high"}, "best_value = 'high'"),
    ({"version": 1}, "not a version-2"),
])
def test_corrupt_checkpoint_state_is_rejected(tmp_path, changes, match):
    tiger_run(tmp_path)
    rewrite_checkpoint(tmp_path / "tiger.safetensors", **changes)
    with pytest.raises(ValueError, match=match):
        tiger_run(tmp_path)


def test_monte_carlo_evaluation_and_reevaluation(toy_env):
    env = toy_env(gamma=0.9, horizon=10.0, exponential=(0, 1, 2), rate=1.0)
    cfg = GDICEConfig(num_nodes=2, iterations=3, samples=10, elites=2)
    res = gdice(MonteCarloEvaluator(env, 16), 2, 3, 2, cfg, seed=0, reevaluator=MonteCarloEvaluator(env, 500))
    assert res.stderr > 0 and math.isfinite(res.value)
    assert res.best.num_controllers == 1


def test_layered_graph_and_injection():
    cfg = GDICEConfig(num_nodes=7, layer_width=3, injection_weight=0.5, injection_threshold=1.0, injection_until=1.0)
    mask = cfg.transition_mask()
    assert mask[0].tolist() == [False, True, True, True, False, False, False]
    assert mask[1:4, 4:].all() and not mask[1:4, :4].any() and mask[4:, 4:].all() and not mask[4:, :4].any()
    g = torch.Generator().manual_seed(0)
    probs = torch.zeros(2, 7, 2, 7, dtype=torch.float64)
    probs[..., :] = mask.to(torch.float64)[None, :, None, :] / mask.sum(-1)[None, :, None, None]
    ctrl = sample_controllers(torch.full((2, 7, 3), 1 / 3, dtype=torch.float64), probs, 200, g)
    rows = torch.arange(7)[None, None, :, None].expand_as(ctrl.next_node)
    assert mask[rows, ctrl.next_node].all()
    env = TabularDecPOSMDP.from_file(BENCH / "dectiger.dpomdp", gamma=1.0, horizon=3)
    res = run(env, GDICEConfig(num_nodes=7, iterations=3, samples=50, elites=5, layer_width=3,
                               injection_weight=0.5, injection_threshold=1.0, injection_until=1.0), seed=0)
    assert mask[torch.arange(7)[None, :, None].expand(2, 7, 2), res.best.next_node[0]].all()
    assert ((res.next_probs > 0) == mask[None, :, None, :]).all()  # injection stays inside the layers


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_nodes": 0}, "num_nodes"),
        ({"elites": 11, "samples": 10}, "elites"),
        ({"alpha": 0.0}, "alpha"),
        ({"injection_weight": 1.5}, "injection_weight"),
        ({"num_nodes": 6, "layer_width": 2}, "layer_width"),
        ({"threshold_rule": "median"}, "threshold_rule"),
        ({"init_weight": -0.1}, "init_weight"),
        ({"init_weight": 1.5}, "init_weight"),
    ],
)
def test_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        GDICEConfig(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    ({"alpha": "0.1"}, r"alpha: expected a number, got '0.1' \(str\)"),
    ({"num_nodes": 2.5}, "num_nodes: expected an int"),
    ({"samples": True}, "samples: expected an int"),
    ({"layer_width": "3"}, "layer_width: expected an int"),
])
def test_config_type_errors(kwargs, match):
    with pytest.raises(TypeError, match=match):
        GDICEConfig(**kwargs)


def test_numpy_and_torch_scalars_are_numbers():
    cfg = GDICEConfig(num_nodes=np.int64(3), iterations=torch.tensor(2), samples=np.int32(6), elites=2,
                      alpha=np.float32(0.25), init_weight=torch.tensor(0.0, dtype=torch.float64))
    assert cfg == GDICEConfig(num_nodes=3, iterations=2, samples=6, elites=2, alpha=0.25)
    assert type(cfg.num_nodes) is int and type(cfg.alpha) is float
    env = dec_tiger(3)
    a = gdice(ExactEvaluator(env), np.int64(2), torch.tensor(3), np.int16(2), cfg, seed=np.int64(4))
    b = gdice(ExactEvaluator(env), 2, 3, 2, cfg, seed=4)
    assert a.history == b.history


def test_argument_errors(recycling):
    ev = ExactEvaluator(recycling)
    with pytest.raises(TypeError, match="config"):
        gdice(ev, 2, 3, 2, config={"num_nodes": 2})
    with pytest.raises(ValueError, match="num_actions"):
        gdice(ev, 2, 0, 2)
    with pytest.raises(TypeError, match="evaluator"):
        gdice(None, 2, 3, 2)
    with pytest.raises(ValueError, match="budget"):
        monte_carlo_search(ev, 2, 3, 2, num_nodes=2, budget=0)
    assert isinstance(run(recycling, GDICEConfig(num_nodes=1, iterations=1, samples=2, elites=1)).best, JointController)


def recycling_controller(num_nodes=2):
    """A fixed 2-agent recycling controller with ``num_nodes`` nodes (next node depends on node and obs)."""
    g = torch.Generator().manual_seed(11)
    return JointController(torch.randint(0, 3, (1, 2, num_nodes), generator=g),
                           torch.randint(0, num_nodes, (1, 2, num_nodes, 2), generator=g))


@pytest.mark.parametrize("init_nodes", [2, 3])
def test_warm_start_at_weight_one_samples_the_init_controller(recycling, init_nodes):
    init = recycling_controller(init_nodes)
    target = exact_value(recycling, init).item()
    res = run(recycling, GDICEConfig(num_nodes=3, iterations=1, samples=8, elites=2, init_weight=1.0), seed=0,
              init=init)
    # exact evaluation: every first-iteration sample is ``init`` (padding node unreachable), so all values agree
    assert res.history["iteration_best"][0] == pytest.approx(target, abs=1e-9)
    assert res.history["iteration_mean"][0] == pytest.approx(target, abs=1e-9)
    assert torch.equal(res.best.action[..., :init_nodes], init.action)
    assert torch.equal(res.best.next_node[..., :init_nodes, :], init.next_node)
    assert res.action_probs.shape == (2, 3, 3) and res.next_probs.shape == (2, 3, 2, 3)


def test_warm_start_distributions(recycling):
    init = recycling_controller(2)
    w = 0.6
    cfg = GDICEConfig(num_nodes=3, iterations=1, samples=4, elites=4, alpha=1e-12, init_weight=w)
    res = run(recycling, cfg, seed=0, init=init)
    # alpha ~ 0: the final distributions are the initial ones up to 1e-12
    act = torch.full((2, 3, 3), (1 - w) / 3, dtype=torch.float64)
    act[:, :2] += w * torch.nn.functional.one_hot(init.action[0], 3).double()
    nxt = torch.full((2, 3, 2, 3), (1 - w) / 3, dtype=torch.float64)
    nxt[:, :2] += w * torch.nn.functional.one_hot(init.next_node[0], 3).double()
    nxt[:, 2] = 1 / 3  # the node the init controller lacks stays uniform
    act[:, 2] = 1 / 3
    torch.testing.assert_close(res.action_probs, act, rtol=0, atol=1e-10)
    torch.testing.assert_close(res.next_probs, nxt, rtol=0, atol=1e-10)
    # the warm start speeds the search up: a warm start from the cold-start best sample is at least as good
    cold = run(recycling, GDICEConfig(num_nodes=2, iterations=3, samples=20, elites=4), seed=1)
    warm = run(recycling, GDICEConfig(num_nodes=2, iterations=3, samples=20, elites=4, init_weight=0.9), seed=1,
               init=cold.best)
    assert warm.best_value >= cold.best_value


def test_warm_start_errors(recycling, tmp_path):
    ev, init = ExactEvaluator(recycling), recycling_controller(2)
    cfg = GDICEConfig(num_nodes=2, iterations=1, samples=4, elites=2, init_weight=0.5)
    with pytest.raises(ValueError, match="init_weight"):
        gdice(ev, 2, 3, 2, cfg)
    with pytest.raises(ValueError, match="no effect"):
        gdice(ev, 2, 3, 2, GDICEConfig(num_nodes=2, iterations=1, samples=4, elites=2), init=init)
    with pytest.raises(TypeError, match="init"):
        gdice(ev, 2, 3, 2, cfg, init=init.action)
    with pytest.raises(ValueError, match="init: expected shape"):
        gdice(ev, 2, 3, 2, cfg, init=recycling_controller(3))  # more nodes than num_nodes
    with pytest.raises(ValueError, match="init: expected shape"):
        gdice(ev, 2, 3, 2, cfg, init=JointController.cat([init, init]))
    with pytest.raises(ValueError, match="init: expected shape"):
        gdice(ev, 2, 3, 2, cfg, init=init[0].__class__(init.action[:, :1], init.next_node[:, :1]))
    with pytest.raises(ValueError, match="actions"):
        gdice(ev, 2, 2, 2, cfg, init=JointController(torch.full((1, 2, 2), 2), init.next_node))
    layered = GDICEConfig(num_nodes=3, layer_width=2, iterations=1, samples=4, elites=2, init_weight=0.5)
    with pytest.raises(ValueError, match="layered"):
        gdice(ev, 2, 3, 2, layered, init=JointController(torch.zeros(1, 2, 3, dtype=torch.long),
                                                          torch.zeros(1, 2, 3, 2, dtype=torch.long)))
    ckpt = tmp_path / "warm.safetensors"
    gdice(ev, 2, 3, 2, cfg, init=init, checkpoint=ckpt)
    other = JointController(init.action, 1 - init.next_node)
    with pytest.raises(ValueError, match="another run: init was "):
        gdice(ev, 2, 3, 2, cfg, init=other, checkpoint=ckpt)


class Scripted:
    """An evaluator returning scripted values per iteration (sample j of iteration i scores ``values[i][j]``)."""

    def __init__(self, values):
        self.values, self.calls = values, 0

    def __call__(self, ctrl, generator):
        v = torch.tensor(self.values[self.calls], dtype=torch.float64)
        self.calls += 1
        return v, torch.zeros_like(v)


def test_threshold_rules():
    # iteration 0 is "lucky": its worst elite (9) is above everything iteration 1 and 2 sample
    values = [[10.0, 9.0, 1.0, 0.0], [5.0, 4.0, 3.0, 2.0], [8.0, 7.0, 6.0, 0.0]]
    paper = gdice(Scripted(values), 1, 2, 2, GDICEConfig(num_nodes=2, iterations=3, samples=4, elites=2), seed=0)
    assert paper.history["kept"] == [2.0, 0.0, 0.0] and paper.history["threshold"] == [9.0, 9.0, 9.0]
    capped = gdice(Scripted(values), 1, 2, 2, GDICEConfig(num_nodes=2, iterations=3, samples=4, elites=2,
                                                           threshold_rule="capped"), seed=0)
    # capped at the current N_b-th best: 4 in iteration 1; in iteration 2 the rule (>= 4) admits 8 and 7 again
    assert capped.history["kept"] == [2.0, 2.0, 2.0] and capped.history["threshold"] == [9.0, 4.0, 7.0]
    # identical while the paper's rule admits N_b samples
    rising = [[1.0, 0.0, 0.0, 0.0], [2.0, 1.5, 0.0, 0.0], [3.0, 2.5, 2.0, 0.0]]
    a = gdice(Scripted(rising), 1, 2, 2, GDICEConfig(num_nodes=2, iterations=3, samples=4, elites=2), seed=0)
    b = gdice(Scripted(rising), 1, 2, 2, GDICEConfig(num_nodes=2, iterations=3, samples=4, elites=2,
                                                      threshold_rule="capped"), seed=0)
    assert a.history == b.history
    torch.testing.assert_close(a.next_probs, b.next_probs, rtol=0, atol=0)
