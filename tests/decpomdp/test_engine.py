"""The compiled engine against its oracle, the batched torch simulator, and its own guarantees.

Statistical comparisons use ``n`` rollouts on each backend. Means must agree within 4 combined
standard errors; variances within 4 standard errors of the difference of two sample variances, each
with the fourth-moment standard error ``sqrt((m4 - s^4) / n)`` (an F-test that stays valid for the
skewed, discrete returns of these domains). There are about 150 such comparisons: at 4 standard
errors the chance that any fails by luck is below 1 %.
"""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import hbni_pyro
from decpomdp import JointController, random_controllers, simulate
from decpomdp.core import DecPOSMDP
from decpomdp.domains import DisasterRelief, PackageDelivery, rollout_counters
from decpomdp.domains import disaster_relief as dr
from decpomdp.domains import package_delivery as pd
from decpomdp.dpomdp import TabularDecPOSMDP
from decpomdp.engine import OutcomeTable, outcome_table, run
from decpomdp.engine.runner import chunk_bounds, table_dtype
from decpomdp.perception import PerfectPerception
from decpomdp.search import RolloutScorer, plan
from hbni_pyro import sample_outputs
from hbni_infra.threads import threads
from planner_settings import SHORT

ROOT = Path(__file__).resolve().parents[2]
N = 3000


def g(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def table() -> hbni_pyro.MacroObservationModel:
    """A six-class macro-observation table with errors and spread-out frame counts."""
    joint = (
        torch.distributions.Dirichlet(torch.ones(6 * 12, dtype=torch.float64))
        .sample(
            (6,),
        )
        .view(6, 6, 12)
    )
    joint[torch.arange(6), torch.arange(6)] += 0.5  # mostly right
    return hbni_pyro.MacroObservationModel(joint / joint.sum((1, 2), keepdim=True), torch.zeros(6))


def replay() -> hbni_pyro.StreamReplay:
    """SSBF run on recorded six-class streams (7 per class, 20 frames each)."""
    theta = torch.tensor([1.0, 3.0, 2.0, 6.0, 4.0, 1.5])
    truth = torch.arange(6).repeat_interleave(7)
    streams = torch.stack([sample_outputs(theta, c.repeat(20), g(int(i))) for i, c in enumerate(truth)])
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(6), threshold=0.9, max_frames=20)
    return hbni_pyro.StreamReplay(process, streams, truth)


def planned(env: DecPOSMDP) -> JointController:
    """A controller found by a short cold-start run on ``env``."""
    return plan(RolloutScorer(env), SHORT, seed=0).best


torch.manual_seed(0)
DOMAINS = {
    "disaster relief, perfect": lambda: DisasterRelief(),
    "disaster relief, table": lambda: DisasterRelief(perception=table(), wrong_penalty=0.5),
    "disaster relief, replay": lambda: DisasterRelief(perception=replay(), num_agents=3),
    "package delivery": lambda: PackageDelivery(),
    "package delivery, solo joint": lambda: PackageDelivery(solo_joint=True, large_reward_per_robot=False),
    "package delivery, reference": lambda: PackageDelivery(
        solo_joint=True, successor_rule=True, reference_pickup=True, truck_reward=0.0
    ),
    "dectiger h4": lambda: TabularDecPOSMDP.from_problem("dectiger", horizon=4),
    "recycling h6": lambda: TabularDecPOSMDP.from_problem("recycling", horizon=6),
}


def greedy(env: DecPOSMDP) -> JointController | None:
    if isinstance(env, DisasterRelief):
        return dr.greedy_controller(env.num_agents)
    return pd.greedy_controller() if isinstance(env, PackageDelivery) else None


def mutants(controller: JointController, count: int) -> JointController:
    """``controller`` and ``count - 1`` copies, each with one MA changed."""
    action = controller.action.expand(count, -1, -1).clone()
    for k in range(1, count):
        action[k, k % controller.num_agents, k % controller.num_nodes] = k % 9
    return JointController(action, controller.next_node.expand(count, -1, -1, -1).clone())


def assert_same_law(x: torch.Tensor, y: torch.Tensor, what: str) -> None:
    """Means within 4 combined standard errors, variances within 4 standard errors (module doc)."""
    x, y = x.double().flatten(), y.double().flatten()
    if float(x.var()) == 0 and float(y.var()) == 0:
        assert float(x[0]) == float(y[0]), what
        return
    se = math.sqrt((x.var() / x.numel() + y.var() / y.numel()).item())
    assert abs(float(x.mean() - y.mean())) < 4 * se, f"{what}: means {float(x.mean()):.4f} vs {float(y.mean()):.4f}"

    def var_se(v):
        c = v - v.mean()
        return ((c**4).mean() - c.var() ** 2) / v.numel()

    vse = math.sqrt(max(float(var_se(x) + var_se(y)), 0.0))
    assert abs(float(x.var() - y.var())) <= 4 * vse + 1e-12, (
        f"{what}: variances {float(x.var()):.4f} vs {float(y.var()):.4f}"
    )


@pytest.mark.parametrize("name", DOMAINS)
def test_engine_matches_the_torch_oracle(name):
    env = DOMAINS[name]()
    controllers = {
        "random": random_controllers(
            2, num_agents=env.num_agents, num_nodes=4, num_actions=env.num_actions, num_obs=env.num_obs, generator=g(1)
        ),
        "planned": planned(env),
    }
    if greedy(env) is not None:
        controllers["greedy"] = greedy(env)
    for kind, ctrl in controllers.items():
        for k in range(ctrl.num_controllers):
            one = ctrl[k]
            r_e, c_e = rollout_counters(env, one, N, g(2), backend="engine")
            r_t, c_t = rollout_counters(env, one, N, g(3), backend="torch")
            assert_same_law(r_e, r_t, f"{name}, {kind} {k}: return")
            for key in c_e:
                assert_same_law(c_e[key], c_t[key], f"{name}, {kind} {k}: {key}")


# ---- where nothing is random, both give the same numbers -------------------------------------------


class FromState(DecPOSMDP):
    """The torch oracle of ``env`` started from one given state, remembering the state after every rule."""

    def __init__(self, env: DecPOSMDP, state: dict[str, torch.Tensor]) -> None:
        self.env, self.state = env, state
        for name in ("num_agents", "num_actions", "num_obs", "gamma", "horizon", "action_names", "obs_names"):
            setattr(self, name, getattr(env, name))

    def reset(self, batch, generator):
        return {k: v.clone() for k, v in self.state.items()}

    def start(self, state, agents, actions, t, end_time, generator):
        end = self.env.start(state, agents, actions, t, end_time, generator)
        self.last = {k: v.clone() for k, v in state.items()}
        return end

    def complete(self, state, agents, actions, t, generator):
        out = self.env.complete(state, agents, actions, t, generator)
        self.last = {k: v.clone() for k, v in state.items()}
        return out


RENAME = {"objects": ("object_base1", "object_base2"), "base": ("base1", "base2")}


def flat(state: dict[str, torch.Tensor]) -> dict[str, float]:
    """A one-rollout torch state as the engine's named entries."""
    out = {}
    for key, value in state.items():
        value = value[0]
        if value.dim() == 0:
            out[key] = float(value)
        else:
            for a, v in enumerate(value.tolist()):
                out[RENAME[key][a] if key in RENAME else f"{key}[{a}]"] = float(v)
    return out


def both(env: DecPOSMDP, ctrl: JointController, state: dict[str, torch.Tensor]):
    """(return, final state) on the engine and on the oracle, from ``state``."""
    oracle = FromState(env, state)
    r_t = float(simulate(oracle, ctrl, 1, g(), backend="torch")[0, 0])
    e = run(env, ctrl, 1, 5, initial_state=flat(state), keep_state=True)
    return (float(e.returns[0, 0]), {k: float(v[0, 0]) for k, v in e.final_state.items()}), (r_t, flat(oracle.last))


def one_ma(*mas: int, num_obs: int) -> JointController:
    """Each robot runs its MA again and again."""
    a = len(mas)
    return JointController(torch.tensor([list(mas)]).view(1, a, 1), torch.zeros(1, a, 1, num_obs, dtype=torch.long))


DR_STATES = {
    "at base1": {},
    "at base2, a fresh inference": {"loc": 1, "fresh": 1, "label": 3},
    "at the hospital with an ambulance": {"loc": 2, "carry": 0},
    "at the airport with an ambulance": {"loc": 3, "carry": 0, "belief": 0},
    "at the repair station, low health": {"loc": 5, "health": 2},
    "at base1 carrying a crate": {"carry": 4},
}


def dr_state(env: DisasterRelief, **entries) -> dict[str, torch.Tensor]:
    state = env.reset(1, g(9))
    state["objects"][:] = torch.tensor([[2, 5]])
    for key, value in entries.items():
        state[key][:, 0] = value
    return state


@pytest.mark.parametrize("situation", DR_STATES)
@pytest.mark.parametrize("ma", range(len(dr.ACTION_NAMES)), ids=dr.ACTION_NAMES)
def test_every_disaster_relief_ma_on_both_implementations(ma, situation, monkeypatch):
    monkeypatch.setattr(dr.rules, "DURATION_NOISE", 0.0)
    env = DisasterRelief(num_agents=1, degrade_prob=0.0, sensor_accuracy=1.0, wrong_penalty=0.5, horizon=3.5)
    (r_e, s_e), (r_t, s_t) = both(env, one_ma(ma, num_obs=env.num_obs), dr_state(env, **DR_STATES[situation]))
    picked = s_e["carry[0]"] != DR_STATES[situation].get("carry", -1)  # a pick-up draws a new object
    skip = {"object_base1", "object_base2"} if picked else set()
    assert r_e == pytest.approx(r_t, abs=1e-12)
    assert {k: v for k, v in s_e.items() if k not in skip} == {k: v for k, v in s_t.items() if k not in skip}


def test_two_robots_picking_at_one_base_on_both_implementations(monkeypatch):
    monkeypatch.setattr(dr.rules, "DURATION_NOISE", 0.0)
    env = DisasterRelief(degrade_prob=1.0, sensor_accuracy=1.0, horizon=0.5)
    state = dr_state(env)
    state["loc"][:] = 0
    (_, s_e), (_, s_t) = both(env, one_ma(dr.PICK, dr.PICK, num_obs=env.num_obs), state)
    assert s_e["carry[0]"] == s_t["carry[0]"] == 2  # robot 0 takes the waiting object, robot 1 its replacement
    assert 0 <= s_e["carry[1]"] < 6 and s_e["ok[1]"] == s_t["ok[1]"] == 1


def test_deterministic_package_delivery_gives_equal_returns(monkeypatch):
    monkeypatch.setattr(pd.rules, "DURATION_NOISE", 0.0)
    monkeypatch.setattr(pd.rules, "ARRIVAL", torch.tensor([3], dtype=torch.int32))  # large, to Dest1: joint MAs
    env = PackageDelivery()
    ctrl = pd.greedy_controller()
    e, t = simulate(env, ctrl, 3, g(1), backend="engine"), simulate(env, ctrl, 3, g(2), backend="torch")
    assert torch.allclose(e, t, rtol=0, atol=1e-12) and float(e[0, 0]) > 0


# ---- the engine's own guarantees ------------------------------------------------------------------


def test_a_seed_gives_the_same_returns_on_any_thread_count_and_chunking():
    env, ctrl = DisasterRelief(perception=table()), mutants(dr.greedy_controller(), 6)
    with threads(1):
        one = run(env, ctrl, 700, 11).returns
    with threads(2):
        two = run(env, ctrl, 700, 11).returns
        halves = torch.cat(
            [run(env, ctrl[:3], 700, 11).returns, run(env, ctrl[3:], 700, 11, first_controller=3).returns]
        )
        fewer = run(env, ctrl, 300, 11).returns
    assert torch.equal(one, two) and torch.equal(one, halves) and torch.equal(one[:, :300], fewer)
    assert not torch.equal(one, run(env, ctrl, 700, 12).returns)


@pytest.mark.parametrize("batch,threads_", [(0, 1), (1, 2), (255, 2), (5000, 1), (64000, 2), (32000, 16)])
def test_chunks_cover_the_batch_largest_first(batch, threads_):
    bounds = chunk_bounds(batch, threads_)
    sizes = [hi - lo for lo, hi in zip(bounds, bounds[1:])]
    assert bounds[0] == 0 and bounds[-1] == batch and len(sizes) >= 1
    assert all(s > 0 for s in sizes) or batch == 0
    assert sizes == sorted(sizes, reverse=True)  # the small chunks come last, to even out the threads' ends
    assert all(s >= 256 for s in sizes[:-1])
    if batch >= 4096 * threads_:
        assert sizes[0] == batch // (2 * threads_) and len(sizes) < 40


def test_simulate_is_seeded_by_its_generator():
    env, ctrl = PackageDelivery(), pd.greedy_controller()
    assert torch.equal(simulate(env, ctrl, 50, g(7)), simulate(env, ctrl, 50, g(7)))
    assert not torch.equal(simulate(env, ctrl, 50, g(7)), simulate(env, ctrl, 50, g(8)))


def test_visit_counts_match_the_oracle():
    env = DisasterRelief()
    ctrl = dr.greedy_controller()
    e, t = RolloutScorer(env, backend="engine"), RolloutScorer(env, backend="torch")
    v_e, v_t = e.visits(ctrl, 4000, g(1)), t.visits(ctrl, 4000, g(2))
    assert v_e.shape == v_t.shape == (2, 8, 30)
    assert float((v_e - v_t).abs().sum()) < 0.05 * float(v_t.sum())
    assert torch.equal(v_e.sum(-1) > 0, v_t.sum(-1) > 0)


def test_backend_choice_and_errors():
    class Custom:  # a perception model with no outcome table
        num_classes = 6

        def sample(self, true_class, generator):
            return true_class.clone(), torch.ones_like(true_class)

    env = DisasterRelief(perception=Custom())
    ctrl = dr.greedy_controller()
    assert simulate(env, ctrl, 5, g()).shape == (1, 5)  # runs on torch
    with pytest.raises(ValueError, match="backend"):
        simulate(env, ctrl, 5, g(), backend="engine")
    with pytest.raises(ValueError, match="backend"):
        simulate(DisasterRelief(), ctrl, 5, g(), backend="cuda")
    with pytest.raises(ValueError, match="initial_state"):
        run(DisasterRelief(), ctrl, 2, 0, initial_state={"nope": 1})
    with pytest.raises(ValueError, match="keys"):
        rollout_counters(DisasterRelief(), ctrl, 2, g(), keys=("nope",))


def test_outcome_tables_are_checked_and_sample_their_law():
    perfect = outcome_table(PerfectPerception(6, frames=4))
    assert isinstance(perfect, OutcomeTable) and perfect.label[:, 0].tolist() == list(range(6))
    assert outcome_table(object()) is None

    class Bad:
        num_classes = 2

        def __init__(self, probs, label):
            self.probs, self.label = probs, label

        def outcomes(self):
            return self.probs, self.label, np.ones_like(self.label)

    with pytest.raises(ValueError, match="sum to 1"):
        outcome_table(Bad(np.array([[0.5, 0.4], [1.0, 0.0]]), np.zeros((2, 2), dtype=int)))
    with pytest.raises(ValueError, match="labels"):
        outcome_table(Bad(np.array([[1.0, 0.0], [1.0, 0.0]]), np.array([[2, 0], [0, 0]])))
    # the engine draws each inference's outcome from the table: one inference per rollout (the horizon ends
    # before it completes), its label against the table's confusion row of the object's class
    model = table()
    env = DisasterRelief(perception=model, num_agents=1, horizon=0.05)
    ctrl = JointController(torch.tensor([[[dr.INFER]]]), torch.zeros(1, 1, 1, 30, dtype=torch.long))
    final = run(env, ctrl, 12_000, 3, keep_state=True).final_state
    truth, label, frames = final["object_base1"][0], final["label[0]"][0], final["frames[0]"][0]
    for c in range(6):
        mine = truth == c
        right = (label[mine] == c).double()
        p = float(model.accuracy[c])
        assert abs(float(right.mean()) - p) < 4 * math.sqrt(p * (1 - p) / int(mine.sum()))
        mean_frames = float(model.mean_frames[c])
        support = torch.arange(1, 13, dtype=torch.float64)
        sd = math.sqrt(float(model.frames_pmf[c] @ (support - mean_frames) ** 2) / int(mine.sum()))
        assert abs(float(frames[mine].double().mean()) - mean_frames) < 4 * sd


def load_docs_domain(tmp_path: Path, name: str, edit=lambda text: text) -> dict:
    """The first Python block of docs/engine.md, edited, as a module imported from a file."""
    block = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "engine.md").read_text(), re.S)[0]
    path = tmp_path / f"{name}.py"
    path.write_text(edit(block))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return vars(module)


def test_zero_durations_are_refused(tmp_path):
    rule = "end[a] = t + (1.0 + uniform(rng) if actions[a] == FORAGE else 1.0)"
    module = load_docs_domain(
        tmp_path, "zero_domain", lambda text: text.replace(rule, "end[a] = t").split("always_forage =")[0]
    )
    ctrl = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
    with pytest.raises(RuntimeError, match="zero duration"):
        simulate(module["Foraging"](), ctrl, 3, g())
    with pytest.raises(NotImplementedError, match="engine only"):
        simulate(module["Foraging"](), ctrl, 3, g(), backend="torch")


def test_the_documented_domain_runs(tmp_path):
    module = load_docs_domain(tmp_path, "foraging_domain")
    # always forage: each robot forages back to back (1.5 units on average) and finds with p = 0.3
    assert 0.5 < float(module["returns"].mean()) < 5.0
    _, counters = rollout_counters(module["Foraging"](), module["always_forage"], 2000, g())
    assert float(counters["found"].double().mean()) == pytest.approx(2 * 0.3 * 20 / 1.5, rel=0.1)


def test_controllers_too_large_for_int16_tables_run_on_int32(tmp_path):
    assert table_dtype(32768, 13) is np.int16 and table_dtype(12, 32768) is np.int16
    assert table_dtype(32769, 13) is np.int32 and table_dtype(2, 40000) is np.int32
    module = load_docs_domain(tmp_path, "wide_foraging_domain", lambda text: text.split("always_forage =")[0])
    # every node forages and steps to the next whatever it sees: the same rollouts as one foraging node
    nodes = 32769
    cycle = torch.arange(1, nodes + 1) % nodes
    wide = JointController(
        torch.zeros(1, 2, nodes, dtype=torch.long), cycle.view(1, 1, nodes, 1).expand(1, 2, nodes, 2).contiguous()
    )
    one = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
    env = module["Foraging"]()
    assert torch.equal(run(env, wide, 500, 5).returns, run(env, one, 500, 5).returns)


def test_the_two_agent_loop_stops_on_another_number_of_agents():
    """Package delivery compiles the loop for two robots only; controllers of one robot reach it only past the
    callers' size checks, and it refuses them instead of reading a second robot that is not there."""
    obs = PackageDelivery().num_obs
    one = JointController(torch.zeros(1, 1, 1, dtype=torch.long), torch.zeros(1, 1, 1, obs, dtype=torch.long))
    with pytest.raises(ValueError, match="runs two agents, got 1"):
        run(PackageDelivery(), one, 2, seed=0)
