"""Disaster relief semantics: durations, health, repair, sensor, the plugged perception model, counters."""

import math

import pytest
import torch

from decpomdp import JointController, simulate
from decpomdp.domains import DisasterRelief, rollout_counters
from decpomdp.domains import disaster_relief as dr
from decpomdp.perception import PerfectPerception, check_true_class


def g(seed=0):
    return torch.Generator().manual_seed(seed)


class ShiftedPerception:
    """Reports a class with another destination (``WRONG[true]``) after ``frames`` frames; records what it was asked."""

    WRONG = torch.tensor([1, 0, 3, 2, 0, 1])

    num_classes = 6

    def __init__(self, frames=7):
        self.frames, self.asked = frames, []

    def sample(self, true_class, generator):
        check_true_class(true_class, 6)
        self.asked.append(true_class.clone())
        return self.WRONG[true_class], torch.full_like(true_class, self.frames)

    def outcomes(self):
        return torch.ones(6, 1, dtype=torch.float64), self.WRONG[:, None], torch.full((6, 1), self.frames)


def cycle(*per_agent, num_obs=dr.DisasterRelief.num_obs):
    nodes = max(len(seq) for seq in per_agent)
    action = torch.full((1, len(per_agent), nodes), dr.INFER)
    next_node = torch.zeros(1, len(per_agent), nodes, num_obs, dtype=torch.long)
    for a, seq in enumerate(per_agent):
        action[0, a, : len(seq)] = torch.tensor(seq)
        next_node[0, a, : len(seq)] = (torch.arange(len(seq)) + 1).remainder(len(seq))[:, None]
    return JointController(action, next_node)


@pytest.fixture
def no_noise(monkeypatch):
    monkeypatch.setattr(dr.rules, "DURATION_NOISE", 0.0)


@pytest.fixture
def no_noise_both(no_noise, backend):
    """No duration noise, on both backends."""


def start(env, state, actions, t=0.0, agents=None):
    actions = torch.tensor([actions])
    agents = torch.ones_like(actions, dtype=torch.bool) if agents is None else torch.tensor([agents])
    return env.start(
        state,
        agents,
        actions,
        torch.full((1,), t, dtype=torch.float64),
        torch.zeros(actions.shape, dtype=torch.float64),
        g(),
    )


def test_travel_durations_and_health_slowdown(no_noise):
    env = DisasterRelief(degrade_prob=0.0)
    state = env.reset(1, g())
    assert state["loc"].tolist() == [[dr.BASE1, dr.BASE2]]
    assert start(env, state, [dr.GO_HOSPITAL, dr.GO_AIRPORT]).tolist() == [[3.0, 3.0]]
    state["health"][:] = torch.tensor([[1, 2]])
    assert start(env, state, [dr.GO_HOSPITAL, dr.GO_AIRPORT]).tolist() == [[4.5, 7.5]]
    assert start(env, state, [dr.REPAIR_MA, dr.PICK]).tolist() == [[2 * 1.5 + 1, 2.5]]
    assert start(env, state, [dr.GO_B1, dr.PUT]).tolist() == [[dr.FAIL_DURATION, dr.FAIL_DURATION]]  # invalid


def test_infer_uses_the_plugged_model(no_noise):
    model = ShiftedPerception(frames=7)
    env = DisasterRelief(perception=model, frame_period=0.25)
    state = env.reset(1, g(2))
    objects = state["objects"].clone()
    assert start(env, state, [dr.INFER, dr.INFER]).tolist() == [[1.75, 1.75]]
    assert torch.equal(model.asked[0], objects[0])  # robot a infers the object at base a
    reward, obs = env.complete(
        state, torch.ones(1, 2, dtype=torch.bool), torch.full((1, 2), dr.INFER), torch.full((1,), 1.75), g()
    )
    contexts = [dr.OBS_NAMES[o].rsplit("_", 1)[0] for o in obs[0]]
    expected = ["saw_" + dr.LOCATIONS[int(dr.DESTINATION[int(ShiftedPerception.WRONG[c])])].lower() for c in objects[0]]
    assert contexts == expected
    assert state["inference_frames"].tolist() == [14] and state["inferences"].tolist() == [2]


def test_deliveries_right_and_wrong(no_noise_both):
    # robot 0 infers, picks up, goes to the inferred destination, puts down, returns to Base1
    greedy = dr.greedy_controller(1)
    _, counters = rollout_counters(DisasterRelief(num_agents=1, degrade_prob=0.0), greedy, 50, g(1))
    assert counters["wrong"].sum() == 0 and counters["delivered"].min() >= 4
    wrong_env = DisasterRelief(perception=ShiftedPerception(), num_agents=1, degrade_prob=0.0, wrong_penalty=0.5)
    returns, counters = rollout_counters(wrong_env, greedy, 50, g(1))
    assert counters["delivered"].sum() == 0 and counters["wrong"].min() >= 4
    assert (returns < 0).all()


def test_one_delivery_reward_and_discount(no_noise_both):
    # Base1: pick up (1), go to the hospital (3), put down (1) at t = 5; the object is an ambulance
    env = DisasterRelief(num_agents=1, degrade_prob=0.0, horizon=5.0)
    ctrl = cycle([dr.PICK, dr.GO_HOSPITAL, dr.PUT, dr.GO_B1])
    returns, counters = rollout_counters(env, ctrl, 400, g(3))
    hospital = float((dr.DESTINATION == dr.HOSPITAL).mean())  # 1/3 of the classes
    delivered = counters["delivered"].double()
    assert torch.equal(returns, 0.99**5 * delivered)
    assert abs(delivered.mean().item() - hospital) < 4 * math.sqrt(hospital * (1 - hospital) / 400)
    assert torch.equal(counters["wrong"], 1 - counters["delivered"])


def test_health_degrades_and_repair_restores(no_noise):
    env = DisasterRelief(num_agents=1, degrade_prob=1.0, sensor_accuracy=1.0)
    state = env.reset(1, g())
    one = torch.ones(1, 1, dtype=torch.bool)
    readings = []
    for k, ma in enumerate([dr.GO_B2, dr.GO_B1, dr.GO_B2]):
        end = start(env, state, [ma], t=0.0)
        _, obs = env.complete(state, one, torch.tensor([[ma]]), end[0], g())
        readings.append(dr.OBS_NAMES[obs[0, 0]])
    assert readings == ["at_base_medium", "at_base_low", "at_base_low"] and state["health"].item() == 2
    end = start(env, state, [dr.REPAIR_MA])
    assert end.item() == 2 * 2.5 + dr.REPAIR_TIME  # Base2 -> repair at low health, plus the repair
    _, obs = env.complete(state, one, torch.tensor([[dr.REPAIR_MA]]), end[0], g())
    assert dr.OBS_NAMES[obs[0, 0]] == "away_high" and state["loc"].item() == dr.REPAIR
    assert state["repairs"].item() == 1


def test_contexts_follow_a_delivery(no_noise):
    env = DisasterRelief(num_agents=1, degrade_prob=0.0, sensor_accuracy=1.0)
    state = env.reset(1, g(6))
    one = torch.ones(1, 1, dtype=torch.bool)
    site = dr.LOCATIONS[int(dr.DESTINATION[int(state["objects"][0, 0])])].lower()
    go = {"hospital": dr.GO_HOSPITAL, "airport": dr.GO_AIRPORT, "crate_zone": dr.GO_CRATE}[site]
    seen, t = [], 0.0
    for ma in [dr.INFER, dr.PICK, go, dr.PUT, dr.GO_B1, dr.PICK, dr.GO_B2]:
        end = start(env, state, [ma], t=t)
        t = end.item()
        _, obs = env.complete(state, one, torch.tensor([[ma]]), end[0], g())
        seen.append(dr.OBS_NAMES[obs[0, 0]].rsplit("_", 1)[0])
    assert seen == [
        "saw_" + site,
        "loaded_" + site,
        "at_site_loaded",
        "away",
        "at_base",
        "loaded_unknown",
        "loaded_unknown",
    ]
    assert state["delivered"].item() == 1 and state["loc"].item() == dr.BASE2


def test_degradation_and_sensor_rates():
    n = 20000
    env = DisasterRelief(num_agents=1, degrade_prob=0.3, sensor_accuracy=0.8)
    state = env.reset(n, g(4))
    agents = torch.ones(n, 1, dtype=torch.bool)
    _, obs = env.complete(state, agents, torch.full((n, 1), dr.INFER), torch.ones(n, dtype=torch.float64), g(5))
    degraded = (state["health"] == 1).double().mean().item()
    assert abs(degraded - 0.3) < 4 * math.sqrt(0.3 * 0.7 / n)
    right = ((obs % 3) == state["health"]).double().mean().item()
    assert abs(right - 0.8) < 4 * math.sqrt(0.8 * 0.2 / n)
    wrong = obs[(obs % 3) != state["health"]] % 3
    assert set(wrong.tolist()) <= {0, 1, 2}


def test_greedy_seeded_determinism_and_more_agents(backend):
    env, ctrl = DisasterRelief(), dr.greedy_controller()
    a, b = simulate(env, ctrl, 100, g(7)), simulate(env, ctrl, 100, g(7))
    assert torch.equal(a, b) and not torch.equal(a, simulate(env, ctrl, 100, g(8)))
    three = DisasterRelief(num_agents=3)
    assert simulate(three, dr.greedy_controller(3), 50, g()).mean() > a.mean()


def test_default_perception_is_perfect():
    env = DisasterRelief()
    assert isinstance(env.perception, PerfectPerception) and env.perception.frames == 10


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"perception": object()}, TypeError, "perception"),
        ({"perception": PerfectPerception(5)}, ValueError, "num_classes"),
        ({"num_agents": 0}, ValueError, "num_agents"),
        ({"gamma": 0.0}, ValueError, "gamma"),
        ({"frame_period": 0.0}, ValueError, "frame_period"),
        ({"degrade_prob": 1.5}, ValueError, "degrade_prob"),
        ({"sensor_accuracy": -0.1}, ValueError, "sensor_accuracy"),
        ({"wrong_penalty": math.inf}, ValueError, "wrong_penalty"),
    ],
)
def test_bad_arguments(kwargs, error, match):
    with pytest.raises(error, match=match):
        DisasterRelief(**kwargs)
