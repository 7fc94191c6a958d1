"""Exact controller evaluation against hand values, a brute-force Markov chain built entry by entry (an
independent implementation), Monte Carlo rollouts (3 standard errors), and across its own solvers."""

import math

import numpy as np
import pytest
import torch

from decpomdp import ExactScorer, JointController, RolloutScorer, random_controllers
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value
from tiny_problems import dec_tiger, problem


def layered(count, agents, width, layers, actions, obs, seed):
    """Random layered controllers: node 0, then ``layers - 1`` layers of ``width`` nodes, each moving to the next."""
    g = torch.Generator().manual_seed(seed)
    nodes = 1 + width * (layers - 1)
    layer = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(nodes - 1) // width + 1])
    first = torch.clamp(layer + 1, max=layers - 1) * width - (width - 1)
    nxt = first[None, None, :, None] + torch.randint(width, (count, agents, nodes, obs), generator=g)
    return JointController(torch.randint(actions, (count, agents, nodes), generator=g), nxt)


def brute_force(env, ctrl, horizon):
    """The (joint node, state) Markov chain of each controller, built entry by entry from dense tables."""
    m = env.model
    t, o, r = m.transition.toarray(), m.observation, m.expected_reward()
    n_s, n_jo = t.shape[1], o.shape[-1]
    out = []
    for k in range(ctrl.num_controllers):
        act, nxt = ctrl.action[k].numpy(), ctrl.next_node[k].numpy()
        a_count, nn = act.shape
        q_count = nn**a_count
        big = np.zeros((q_count * n_s, q_count * n_s))
        rew = np.zeros(q_count * n_s)
        for q in range(q_count):
            nodes = [(q // nn ** (a_count - 1 - i)) % nn for i in range(a_count)]
            ja = sum(act[i, nodes[i]] * env.num_actions ** (a_count - 1 - i) for i in range(a_count))
            rew[q * n_s : (q + 1) * n_s] = r[ja]
            for jo in range(n_jo):
                obs = [(jo // env.num_obs ** (a_count - 1 - i)) % env.num_obs for i in range(a_count)]
                q2 = sum(nxt[i, nodes[i], obs[i]] * nn ** (a_count - 1 - i) for i in range(a_count))
                big[q * n_s : (q + 1) * n_s, q2 * n_s : (q2 + 1) * n_s] += t[ja] * o[ja][:, jo][None, :]
        if horizon == math.inf:
            v = np.linalg.solve(np.eye(q_count * n_s) - env.gamma * big, rew)
        else:
            v = np.zeros(q_count * n_s)
            for _ in range(int(horizon)):
                v = rew + env.gamma * big @ v
        out.append(v[:n_s] @ m.start)
    return torch.tensor(out)


def test_hand_values():
    # always listen: -2 per step for both agents together
    listen = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
    assert exact_value(dec_tiger(3), listen).item() == pytest.approx(-6.0)
    assert exact_value(dec_tiger(math.inf, 0.9), listen).item() == pytest.approx(-2.0 / 0.1)
    assert exact_value(dec_tiger(math.inf, 0.9), listen, max_dense=0).item() == pytest.approx(-2.0 / 0.1)
    assert exact_value(dec_tiger(4, 0.5), listen).item() == pytest.approx(-2 * (1 + 0.5 + 0.25 + 0.125))
    # horizon 2: listen, then both open right iff they heard left, else listen (brute force by enumeration)
    act = torch.tensor([[[0, 2], [0, 2]]])
    nxt = torch.tensor([[[[1, 0], [1, 1]], [[1, 0], [1, 1]]]])
    p_obs = dec_tiger(2).model.observation[0]  # (S', JO) after listen-listen; jo order: hl hl, hl hr, hr hl, hr hr
    v_left = -2 + sum(p_obs[0, jo] * {0: 20.0, 1: 9.0, 2: 9.0, 3: -2.0}[jo] for jo in range(4))
    v_right = -2 + sum(p_obs[1, jo] * {0: -50.0, 1: -101.0, 2: -101.0, 3: -2.0}[jo] for jo in range(4))
    assert exact_value(dec_tiger(2), JointController(act, nxt)).item() == pytest.approx(0.5 * v_left + 0.5 * v_right)


@pytest.mark.parametrize(
    "name, gamma, horizon",
    [
        ("dectiger", 1.0, 4),
        ("broadcastChannel", 1.0, 10),
        ("recycling", 0.9, 5),
        ("GridSmall", 1.0, 3),
        ("oneDoor_2_7_0.20_0.00_0_2", 1.0, 3),
        ("recycling", 0.9, math.inf),
        ("GridSmall", 0.9, math.inf),
        ("dectiger", 0.9, math.inf),
        ("broadcastChannel", 0.9, math.inf),
    ],
)
def test_matches_brute_force(name, gamma, horizon):
    env = problem(name, horizon, gamma)
    g = torch.Generator().manual_seed(4)
    ctrls = [
        random_controllers(4, num_agents=2, num_nodes=3, num_actions=env.num_actions, num_obs=env.num_obs, generator=g),
        layered(4, 2, 2, 3, env.num_actions, env.num_obs, seed=5),
    ]
    for ctrl in ctrls:
        ref = brute_force(env, ctrl, horizon)
        torch.testing.assert_close(exact_value(env, ctrl), ref, atol=1e-9, rtol=0)
        if horizon == math.inf:  # the Krylov path on the same systems
            torch.testing.assert_close(exact_value(env, ctrl, max_dense=0), ref, atol=1e-9, rtol=0)


@pytest.mark.parametrize(
    "name, gamma, horizon, nodes",
    [
        ("dectiger", 1.0, 4, 3),
        ("broadcastChannel", 1.0, 10, 3),
        ("recycling", 0.9, math.inf, 3),
        ("GridSmall", 0.9, math.inf, 2),
        ("oneDoor_2_7_0.20_0.00_0_2", 1.0, 6, 3),
        ("fireFighting_2_4_3", 1.0, 4, 3),
    ],
)
def test_exact_matches_monte_carlo(name, gamma, horizon, nodes):
    """Each of 4 controllers within 3 Monte Carlo standard errors (a false alarm has probability 0.27 % per
    controller); the simulator samples next states from the sparse rows, including fireFighting's 2025 states."""
    g = torch.Generator().manual_seed(11)
    env = problem(name, horizon, gamma)
    ctrl = random_controllers(
        4, num_agents=2, num_nodes=nodes, num_actions=env.num_actions, num_obs=env.num_obs, generator=g
    )
    exact = exact_value(env, ctrl)
    if horizon == math.inf:
        env.horizon = 250.0  # gamma ** 250 * max|R| / (1 - gamma) < 1e-9: far below Monte Carlo error
    mean, se = RolloutScorer(env)(ctrl, 2000 if horizon == math.inf else 4000, g)
    # a deterministic return has se 0 and must match exactly
    ok = ((mean - exact).abs() < 3 * se) | ((se < 1e-12) & ((mean - exact).abs() < 1e-9))
    assert bool(ok.all()), (exact, mean, se)


def test_next_state_sampling_follows_the_sparse_rows():
    env = problem("fireFighting_2_4_3", 4, 1.0)
    t = env.model.transition
    row = int(np.argmax(np.diff(t.indptr)))  # the row with the most entries
    ja, s = divmod(row, env.num_states)
    n = 200_000
    draws = env.sample_next_state(torch.full((n,), ja), torch.full((n,), s), torch.Generator().manual_seed(0))
    lo, hi = t.indptr[row], t.indptr[row + 1]
    p = t.data[lo:hi]
    freq = np.array([(draws == c).sum().item() for c in t.indices[lo:hi]]) / n
    assert (draws[:, None] == torch.as_tensor(t.indices[lo:hi])).any(1).all()  # only stored next states
    np.testing.assert_array_less(np.abs(freq - p), 4 * np.sqrt(p * (1 - p) / n) + 1e-12)  # 4 standard errors


def test_infinite_horizon_solvers_agree_with_a_long_finite_horizon():
    env = problem("GridSmall", gamma=0.9)
    ctrl = random_controllers(
        3,
        num_agents=2,
        num_nodes=4,
        num_actions=env.num_actions,
        num_obs=env.num_obs,
        generator=torch.Generator().manual_seed(2),
    )
    dense, krylov = exact_value(env, ctrl), exact_value(env, ctrl, max_dense=0, tol=1e-12)
    long = exact_value(env, ctrl, horizon=400)  # 0.9 ** 400 * max|R| / 0.1 < 1e-17
    torch.testing.assert_close(dense, krylov, atol=1e-10, rtol=0)
    torch.testing.assert_close(dense, long, atol=1e-10, rtol=0)
    mean, se = ExactScorer(env)(ctrl, 1, torch.Generator())
    torch.testing.assert_close(mean, dense)
    assert bool((se == 0).all())


def test_unreachable_nodes_and_memory_budget_do_not_change_values():
    env = problem("recycling", 4, 0.9)
    ctrl = layered(6, 2, 2, 3, env.num_actions, env.num_obs, seed=1)
    base = exact_value(env, ctrl)
    # a layered controller never leaves layer 2 for layer 1: nodes 1..2 are reachable only at step 1,
    # so a node that no transition enters can hold any action without changing the value
    entered = torch.zeros(6, 2, 5, dtype=torch.bool)
    entered.scatter_(2, ctrl.next_node.reshape(6, 2, -1), True)
    entered[:, :, 0] = True
    changed = JointController(torch.where(entered, ctrl.action, (ctrl.action + 1) % env.num_actions), ctrl.next_node)
    torch.testing.assert_close(exact_value(env, changed), base, atol=0, rtol=0)
    for horizon, budget in ((4, 15_000), (math.inf, 500_000)):  # two controllers per chunk
        full = exact_value(env, ctrl, horizon=horizon)
        chunked = exact_value(env, ctrl, horizon=horizon, memory_budget=budget)
        torch.testing.assert_close(chunked, full, atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match="memory_budget: one controller needs up to"):
        exact_value(env, ctrl, memory_budget=100)


def test_errors():
    env = dec_tiger(3)
    ctrl = random_controllers(
        1, num_agents=2, num_nodes=2, num_actions=3, num_obs=2, generator=torch.Generator().manual_seed(0)
    )
    with pytest.raises(ValueError, match="infinite horizon needs gamma < 1"):
        exact_value(env, ctrl, horizon=math.inf)
    with pytest.raises(ValueError, match="horizon"):
        exact_value(env, ctrl, horizon=2.5)
    with pytest.raises(ValueError, match="action entries"):
        exact_value(
            env,
            random_controllers(
                1, num_agents=2, num_nodes=2, num_actions=4, num_obs=2, generator=torch.Generator().manual_seed(0)
            ),
        )
    with pytest.raises(ValueError, match="agents"):
        exact_value(
            env,
            random_controllers(
                1, num_agents=3, num_nodes=2, num_actions=3, num_obs=2, generator=torch.Generator().manual_seed(0)
            ),
        )
    with pytest.raises(TypeError, match="env"):
        exact_value(object(), ctrl)
    with pytest.raises(ValueError, match="memory_budget"):
        exact_value(env, ctrl, memory_budget=0)
    with pytest.raises(ValueError, match="gamma"):
        TabularDecPOSMDP(env.model, gamma=0.0)
    with pytest.raises(ValueError, match="horizon"):
        TabularDecPOSMDP(env.model, horizon=0)
    with pytest.raises(TypeError, match="env"):
        ExactScorer(object())


def test_tabular_env_rejects_rows_that_are_not_distributions():
    from decpomdp.dpomdp import parse_dpomdp

    text = (
        "agents: 2\ndiscount: 1\nvalues: reward\nstates: 2\nstart: uniform\nactions:\n1\n1\nobservations:\n1\n1\n"
        "T: * : 0 : 0 : 0.5\nO: * :\nuniform\nR: * : * : * : * : 1\n"
    )
    with pytest.raises(ValueError, match=r"transition row \(joint action 0, state 1\) sums to 0, not 1"):
        TabularDecPOSMDP(parse_dpomdp(text, check_probabilities=False), horizon=3)
    text = text.replace("T: * : 0 : 0 : 0.5", "T: * :\nidentity").replace("O: * :\nuniform", "O: * : 1 : 0 0 : 0.3")
    with pytest.raises(ValueError, match=r"observation row \(joint action 0, state 0\) sums to 0, not 1"):
        TabularDecPOSMDP(parse_dpomdp(text, check_probabilities=False), horizon=3)


def _bench_exact():
    """benchmarks/bench_exact.py, which keeps the dense product this package used before as its reference."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_exact.py"
    spec = importlib.util.spec_from_file_location("bench_exact", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "name, horizon", [("dectiger", 4), ("broadcastChannel", 6), ("recycling", 4), ("GridSmall", 3)]
)
def test_equals_the_former_dense_product(name, horizon):
    """The factored evaluator reproduces the former (K, Q, S, S', JO) dense product to 1e-9 on the small problems."""
    bench = _bench_exact()
    env = problem(name, horizon, 1.0)
    for ctrl in (
        random_controllers(
            8,
            num_agents=2,
            num_nodes=3,
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            generator=torch.Generator().manual_seed(3),
        ),
        bench.layered_controllers(env, 8, 1 + 3 * (horizon - 1), seed=4),
    ):
        torch.testing.assert_close(
            exact_value(env, ctrl), bench.dense_reference_value(env, ctrl, horizon), atol=1e-9, rtol=0
        )
