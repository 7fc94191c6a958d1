"""Vectorised MH vs Pyro NUTS (jit) on the paper's toy posterior, in one process.

Prints, for each sampler, wall time (warm-up + sampling), the minimum effective sample size
over theta, kappa and gamma, min-ESS per second, the ratio MH / NUTS, and how far apart the
two posterior means are in Monte Carlo standard errors.

    .venv/bin/python benchmarks/bench_samplers.py [--mh-chains 512] [--nuts-samples 1000]
"""

from __future__ import annotations

import argparse

import torch

import hbni_pyro
from hbni_pyro import sample_outputs
from hbni_infra.stats import monte_carlo_z
from hbni_infra.streams import torch_generator


def min_ess_per_second(post: hbni_pyro.HBNIPosterior) -> tuple[float, float, dict]:
    summary = post.summary()
    min_ess = min(row["ess"] for row in summary.values())
    return min_ess, min_ess / post.info["seconds"], summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--mh-chains", type=int, default=512)
    parser.add_argument("--mh-samples", type=int, default=1000)
    parser.add_argument("--mh-warmup", type=int, default=500)
    parser.add_argument("--nuts-chains", type=int, default=2)
    parser.add_argument("--nuts-samples", type=int, default=1000)
    parser.add_argument("--nuts-warmup", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    obs = sample_outputs(
        torch.tensor([1.0, 6.0, 20.0]), torch.arange(3).repeat_interleave(5), torch_generator(args.seed)
    )
    mh = hbni_pyro.fit(
        obs,
        method="mh",
        num_chains=args.mh_chains,
        num_samples=args.mh_samples,
        warmup_steps=args.mh_warmup,
        seed=args.seed,
        progress=False,
    )
    nuts = hbni_pyro.fit(
        obs,
        method="nuts",
        num_chains=args.nuts_chains,
        num_samples=args.nuts_samples,
        warmup_steps=args.nuts_warmup,
        seed=args.seed,
        progress=False,
        jit=True,
    )
    rows = []
    for name, post in (("MH (vectorised)", mh), ("NUTS (jit)", nuts)):
        ess, rate, summary = min_ess_per_second(post)
        rows.append((name, post, ess, rate, summary))
        print(
            f"{name:16s} chains={post.num_chains:4d} draws/chain={post.num_draws:5d} "
            f"time={post.info['seconds']:7.2f}s  min-ESS={ess:9.0f}  min-ESS/s={rate:10.1f}"
        )
    print(f"ratio MH / NUTS in min-ESS/s: {rows[0][3] / rows[1][3]:.0f}x  (floor 100x)")
    print("posterior means (MH vs NUTS, difference in Monte Carlo standard errors):")
    a, b = rows[0][4], rows[1][4]
    for k, z in monte_carlo_z(a, b).items():
        print(f"  {k:9s} {a[k]['mean']:8.3f} vs {b[k]['mean']:8.3f}   |diff| = {abs(z):.2f} SE")


if __name__ == "__main__":
    main()
