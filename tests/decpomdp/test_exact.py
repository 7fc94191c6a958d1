"""Exact controller evaluation against hand values and against Monte Carlo (3 standard errors)."""

import math

import pytest
import torch

from decpomdp import JointController, evaluate, random_controllers
from decpomdp.dpomdp import ExactEvaluator, TabularDecPOSMDP, exact_value

from test_dpomdp_parser import BENCH


def tiger(horizon, gamma=1.0):
    return TabularDecPOSMDP.from_file(BENCH / "dectiger.dpomdp", gamma=gamma, horizon=horizon)


def test_hand_values():
    # always listen: -2 per step for both agents together
    listen = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
    assert exact_value(tiger(3), listen).item() == pytest.approx(-6.0)
    assert exact_value(tiger(math.inf, 0.9), listen).item() == pytest.approx(-2.0 / 0.1)
    assert exact_value(tiger(4, 0.5), listen).item() == pytest.approx(-2 * (1 + 0.5 + 0.25 + 0.125))
    # horizon 2: listen, then both open right iff they heard left, else listen (brute force by enumeration)
    act = torch.tensor([[[0, 2], [0, 2]]])
    nxt = torch.tensor([[[[1, 0], [1, 1]], [[1, 0], [1, 1]]]])
    m = tiger(2).model
    p_obs = m.observation[0]  # (S', JO) after listen-listen; jo order: hl hl, hl hr, hr hl, hr hr
    v_left = -2 + sum(p_obs[0, jo] * {0: 20.0, 1: 9.0, 2: 9.0, 3: -2.0}[jo] for jo in range(4))
    v_right = -2 + sum(p_obs[1, jo] * {0: -50.0, 1: -101.0, 2: -101.0, 3: -2.0}[jo] for jo in range(4))
    assert exact_value(tiger(2), JointController(act, nxt)).item() == pytest.approx(0.5 * v_left + 0.5 * v_right)


@pytest.mark.parametrize(
    "name, gamma, horizon",
    [("dectiger", 1.0, 4), ("broadcastChannel", 1.0, 10), ("recycling", 0.9, math.inf), ("GridSmall", 0.9, math.inf)],
)
def test_exact_matches_monte_carlo(name, gamma, horizon):
    g = torch.Generator().manual_seed(11)
    env = TabularDecPOSMDP.from_file(BENCH / f"{name}.dpomdp", gamma=gamma, horizon=horizon)
    ctrl = random_controllers(4, 2, 3, env.num_actions, env.num_obs, g)
    exact = exact_value(env, ctrl)
    if horizon == math.inf:
        env.horizon = 300.0  # gamma ** 300 * max|R| < 1e-12: truncation far below Monte Carlo error
    mean, se = evaluate(env, ctrl, 4000, g)
    # within 3 Monte Carlo standard errors (a deterministic return has se 0 and must match exactly)
    ok = ((mean - exact).abs() < 3 * se) | ((se < 1e-12) & ((mean - exact).abs() < 1e-9))
    assert bool(ok.all()), (exact, mean, se)


def test_dense_and_iterative_agree():
    env = TabularDecPOSMDP.from_file(BENCH / "GridSmall.dpomdp", gamma=0.9)
    ctrl = random_controllers(3, 2, 3, env.num_actions, env.num_obs, torch.Generator().manual_seed(2))
    torch.testing.assert_close(exact_value(env, ctrl), exact_value(env, ctrl, max_dense=0), atol=1e-8, rtol=0)
    ev = ExactEvaluator(env)
    mean, se = ev(ctrl, torch.Generator())
    torch.testing.assert_close(mean, exact_value(env, ctrl))
    assert bool((se == 0).all())


def test_errors():
    env = tiger(3)
    ctrl = random_controllers(1, 2, 2, 3, 2, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="infinite horizon needs gamma < 1"):
        exact_value(env, ctrl, horizon=math.inf)
    with pytest.raises(ValueError, match="horizon"):
        exact_value(env, ctrl, horizon=2.5)
    with pytest.raises(ValueError, match="action entries"):
        exact_value(env, random_controllers(1, 2, 2, 4, 2, torch.Generator().manual_seed(0)))
    with pytest.raises(ValueError, match="agents"):
        exact_value(env, random_controllers(1, 3, 2, 3, 2, torch.Generator().manual_seed(0)))
    with pytest.raises(TypeError, match="env"):
        exact_value(object(), ctrl)
    with pytest.raises(ValueError, match="gamma"):
        TabularDecPOSMDP(env.model, gamma=0.0)
    with pytest.raises(ValueError, match="horizon"):
        TabularDecPOSMDP(env.model, horizon=0)
