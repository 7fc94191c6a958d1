"""Exact controller evaluation: the factored evaluator against the former dense product, in one run.

Problems of real size: three random sparse problems built here with the shapes reported in issue 11
(100 states / 25 joint observations, 256 / 64, 81 / 81), a 432-state / 4-observation one, and the shipped
``fireFighting_2_4_3`` (2025 states, where the dense product cannot run at all: it would need an
(S x S' x JO) tensor of 1 GB per joint node). Controllers are layered G-DICE samples (7 nodes =
layers of width 3, horizon 3; 10 nodes at horizon 4 on the 81 / 81 problem). Both evaluators are timed
on the same controllers in this process (CPU seconds, single thread) and must agree to 1e-9.
Also prints the parser's speed on every shipped problem.

    python benchmarks/bench_exact.py [--seed 0] [--controllers 100] [--reference 2]
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np
import torch
from torch import Tensor

from hbni_infra.streams import numpy_generator, stream_seed, torch_generator

from decpomdp import JointController
from decpomdp.dpomdp import (
    DPOMDPModel,
    SparseTransitions,
    TabularDecPOSMDP,
    exact_value,
    load_dpomdp,
    problem_names,
    problem_path,
)


def dense_reference_value(env: TabularDecPOSMDP, ctrl: JointController, horizon: int) -> Tensor:
    """The evaluator this package used before: a (K, Q, S, S', JO) tensor per controller chunk (finite horizon)."""
    k, a, nn = ctrl.action.shape
    transition = torch.as_tensor(env.model.transition.toarray())  # (JA, S, S')
    grids = torch.cartesian_prod(*[torch.arange(nn)] * a).view(-1, a) if a > 1 else torch.arange(nn)[:, None]
    agent = torch.arange(a)
    ja = env.joint_action(ctrl.action[:, agent, grids])  # (K, Q)
    obs = env.split_obs(torch.arange(env.observation.shape[-1]))  # (JO, A)
    nxt = ctrl.next_node[:, agent, grids[:, None, :], obs[None, :, :]]
    nxt_q = (nxt * torch.tensor([nn ** (a - 1 - i) for i in range(a)])).sum(-1)  # (K, Q, JO)
    r = env.expected_reward[ja]  # (K, Q, S)
    p = transition[ja][..., None] * env.observation[ja][:, :, None]  # (K, Q, S, S', JO)
    v = torch.zeros_like(r)
    s = r.shape[-1]
    for _ in range(horizon):
        w = torch.gather(v, 1, nxt_q.reshape(k, -1)[..., None].expand(-1, -1, s)).view(k, nxt_q.shape[1], -1, s)
        v = r + env.gamma * torch.einsum("kqsxj,kqjx->kqs", p, w)
    return v[:, 0, :] @ env.start_dist


def random_problem(n_states: int, n_actions: int, n_obs: int, per_row: int, seed: int) -> TabularDecPOSMDP:
    """Two agents; every T row has ``per_row`` random next states; dense random O; R depends on (ja, s)."""
    rng = numpy_generator(seed)
    n_ja, n_jo = n_actions**2, n_obs**2
    cols = np.sort(np.stack([rng.choice(n_states, per_row, replace=False) for _ in range(n_ja * n_states)]), axis=1)
    data = rng.dirichlet(np.ones(per_row), size=n_ja * n_states)
    trans = SparseTransitions(
        n_ja,
        n_states,
        np.arange(0, n_ja * n_states * per_row + 1, per_row),
        cols.ravel().astype(np.int64),
        data.ravel(),
    )
    model = DPOMDPModel(
        agent_names=["0", "1"],
        state_names=[str(i) for i in range(n_states)],
        action_names=[[str(i) for i in range(n_actions)]] * 2,
        obs_names=[[str(i) for i in range(n_obs)]] * 2,
        discount=1.0,
        start=np.full(n_states, 1.0 / n_states),
        transition=trans,
        observation=rng.dirichlet(np.ones(n_jo), size=(n_ja, n_states)),
        reward=rng.normal(size=(n_ja, n_states, 1, 1)),
    )
    return TabularDecPOSMDP(model, gamma=1.0, horizon=3)


def layered_controllers(env: TabularDecPOSMDP, count: int, nodes: int, seed: int, width: int = 3) -> JointController:
    """Uniform random layered controllers: node 0, then layers of ``width`` nodes; each node moves to the next layer."""
    g = torch_generator(seed)
    layer = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(nodes - 1) // width + 1])
    first = torch.clamp(layer + 1, max=int(layer[-1])) * width - (width - 1)  # first node of the next layer
    shape = (count, env.num_agents, nodes, env.num_obs)
    nxt = first[None, None, :, None] + torch.randint(width, shape, generator=g)
    act = torch.randint(env.num_actions, (count, env.num_agents, nodes), generator=g)
    return JointController(act, nxt)


def cpu_time(fn, *args, **kwargs) -> tuple[float, object]:
    """CPU seconds of ``fn(*args, **kwargs)`` and its result."""
    start = time.process_time()
    out = fn(*args, **kwargs)
    return time.process_time() - start, out


def bench_evaluators(args: argparse.Namespace) -> None:
    cases = [
        ("random S=100, JO=25", random_problem(100, 3, 5, 8, args.seed), 7, 3),
        ("random S=432, JO=4", random_problem(432, 4, 2, 8, stream_seed(args.seed, "S=432")), 7, 3),
        ("random S=81, JO=81", random_problem(81, 3, 9, 6, stream_seed(args.seed, "S=81")), 10, 4),
        ("random S=256, JO=64", random_problem(256, 3, 8, 8, stream_seed(args.seed, "S=256")), 7, 3),
        (
            "fireFighting_2_4_3 S=2025, JO=4",
            TabularDecPOSMDP.from_problem("fireFighting_2_4_3", gamma=1.0, horizon=4),
            10,
            4,
        ),
    ]
    print(
        f"{'problem':34s} {'nodes':>5s} {'h':>2s} {'new ctrl/s':>11s} {'dense ctrl/s':>13s} {'speed-up':>9s} {'max |diff|':>10s}"
    )
    for name, env, nodes, horizon in cases:
        ctrl = layered_controllers(env, args.controllers, nodes, args.seed)
        exact_value(env, ctrl[:2], horizon=horizon)  # warm-up (operator build)
        t_new, v_new = cpu_time(exact_value, env, ctrl, horizon=horizon)
        q, s, jo = nodes**2, env.num_states, env.observation.shape[-1]
        dense_bytes = q * s * s * jo * 8 * 2
        if dense_bytes > 4 * 1024**3:
            print(
                f"{name:34s} {nodes:5d} {horizon:2d} {args.controllers / t_new:11.1f} {'n/a':>13s} {'n/a':>9s} {'':>10s}"
                f"  (dense product needs {dense_bytes / 1024**3:.0f} GB per controller)"
            )
            continue
        ref = ctrl[: args.reference]
        t_ref, v_ref = cpu_time(dense_reference_value, env, ref, horizon)
        diff = float((v_ref - v_new[: args.reference]).abs().max())
        new_rate, ref_rate = args.controllers / t_new, args.reference / t_ref
        print(
            f"{name:34s} {nodes:5d} {horizon:2d} {new_rate:11.1f} {ref_rate:13.3f} {new_rate / ref_rate:8.0f}x {diff:10.1e}"
            f"  ({'floor 50x met' if new_rate / ref_rate >= 50 else 'floor 50x NOT met'}; "
            f"{'agree' if diff <= 1e-9 else 'DISAGREE'})"
        )


def bench_parser() -> None:
    print(f"\n{'shipped problem':34s} {'MB':>7s} {'CPU s':>7s} {'MB/s':>7s}")
    for name in problem_names():
        path = problem_path(name)
        check = name != "example"  # example.dpomdp is a syntax tour: its line 199 is an error by design
        if not check:
            continue
        load_dpomdp(path)
        best = math.inf
        for _ in range(3 if os.path.getsize(path) > 100_000 else 30):
            best = min(best, cpu_time(load_dpomdp, path)[0])
        with open(path, "rb") as f:
            raw = f.read()
        size = len(__import__("gzip").decompress(raw)) if raw[:2] == b"\x1f\x8b" else len(raw)
        floors = "floor 5 MB/s " + ("met" if size / best >= 5e6 else "NOT met")
        if name == "fireFighting_2_4_3":
            floors += f", floor 2 s {'met' if best <= 2 else 'NOT met'}"
        print(f"{name:34s} {size / 1e6:7.3f} {best:7.3f} {size / best / 1e6:7.1f}  ({floors})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--controllers", type=int, default=100, help="controllers timed with the new evaluator")
    parser.add_argument("--reference", type=int, default=2, help="controllers timed with the dense product")
    args = parser.parse_args()
    torch.set_num_threads(1)
    bench_evaluators(args)
    bench_parser()


if __name__ == "__main__":
    main()
