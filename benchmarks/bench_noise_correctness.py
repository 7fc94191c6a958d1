"""Correctness study of the noise models' samplers, at a scale the test suite cannot afford.

1. Simulation-based calibration (:func:`hbni_pyro.run_sbc`) of every model's MH kernel on
   ``--datasets`` datasets from its own prior; prints each rank statistic's chi-square p-value
   (10 bins) and the smallest against its Bonferroni floor (family-wise 1 %).
2. MH against NUTS (Pyro, jit) on one small dataset per variant, with longer NUTS runs than the
   tests: prints every scalar's posterior mean under both and their difference in Monte Carlo
   standard errors (from each side's ESS), and the CPU time of each.

Usage, from the repository root: ``python -m benchmarks.bench_noise_correctness [--datasets 400]``
"""

from __future__ import annotations

import argparse
import time

import torch

import hbni_pyro
from hbni_pyro import run_sbc, sample_dirichlet, sample_outputs, sample_sequences
from hbni_pyro.fit import NUTS_SEED_LIMIT
from hbni_infra.stats import monte_carlo_z
from hbni_infra.streams import stream_seed, torch_generator

SBC_CASES = {
    "paper": dict(labelled=False, size=15),
    "confusion": dict(size=30),
    "sequence": dict(size=12, num_frames=5),
}


def sbc(datasets: int, seed: int) -> None:
    for model, kw in SBC_CASES.items():
        cpu = time.process_time()
        r = run_sbc(model, datasets, seed=seed, **kw)
        floor = 0.01 / len(r.p_value)
        worst = min(r.p_value, key=r.p_value.get)
        print(
            f"SBC {model:9s} {datasets} datasets, {r.num_draws} draws each, cpu {time.process_time() - cpu:6.1f} s: "
            f"smallest p = {r.p_value[worst]:.4f} ({worst}), floor {floor:.4f} -> {'uniform' if r.p_value[worst] > floor else 'NOT uniform'}"
        )
        print("   " + ", ".join(f"{k} {p:.3f}" for k, p in r.p_value.items()))


def datasets(seed: int) -> dict[str, tuple]:
    g = torch_generator(seed)
    alpha = torch.tensor([[5.0, 2.0, 0.4], [0.6, 9.0, 0.5], [0.3, 0.3, 4.0]], dtype=torch.float64)
    classes = torch.arange(3).repeat_interleave(5)
    conf = sample_dirichlet(alpha[classes], g)
    conf_labels = torch.where(torch.arange(15) % 3 == 0, torch.tensor(-1), classes)
    loc = torch.tensor([[1.2, 0.1], [-0.7, 1.0], [-0.6, -1.1]], dtype=torch.float64)
    between = torch.eye(2, dtype=torch.float64).expand(3, 2, 2) * 0.3
    seq_classes = torch.arange(3).repeat_interleave(3)
    seqs = sample_sequences(loc, between, 0.4 * torch.eye(2, dtype=torch.float64), seq_classes, 4, g).reshape(-1, 3)
    seq_labels = torch.where(torch.arange(9) % 3 == 1, torch.tensor(-1), seq_classes).repeat_interleave(4)
    paper = sample_outputs(torch.tensor([1.0, 6.0, 20.0]), classes, g)
    return {
        "paper": (paper, None, {}),
        "confusion": (conf, conf_labels, {}),
        "sequence": (seqs, seq_labels, {"sequence_ids": torch.arange(9).repeat_interleave(4)}),
    }


def mh_vs_nuts(seed: int, nuts_samples: int) -> None:
    for model, (obs, labels, extra) in datasets(seed).items():
        cpu = time.process_time()
        mh = hbni_pyro.fit(
            obs,
            labels,
            model=model,
            num_chains=64,
            num_samples=2000,
            warmup_steps=1000,
            seed=seed,
            progress=False,
            **extra,
        )
        mh_cpu, cpu = time.process_time() - cpu, time.process_time()
        nuts = hbni_pyro.fit(
            obs,
            labels,
            model=model,
            method="nuts",
            num_chains=2,
            num_samples=nuts_samples,
            warmup_steps=nuts_samples // 2,
            seed=stream_seed(seed, "nuts") % NUTS_SEED_LIMIT,
            progress=False,
            **extra,
        )
        nuts_cpu = time.process_time() - cpu
        a, b = mh.summary(), nuts.summary()
        z = monte_carlo_z(a, b)
        worst = max(z, key=lambda k: abs(z[k]))
        print(
            f"MH vs NUTS {model:9s} MH cpu {mh_cpu:6.1f} s, NUTS cpu {nuts_cpu:6.1f} s ({nuts.info['divergences']} divergences): "
            f"{len(z)} scalars, largest |z| = {abs(z[worst]):.2f} ({worst}); |z| > 3 for {sum(abs(v) > 3 for v in z.values())}"
        )
        for k in a:
            print(
                f"   {k:18s} MH {a[k]['mean']:9.4f} (ess {a[k]['ess']:7.0f})  NUTS {b[k]['mean']:9.4f} (ess {b[k]['ess']:6.0f})  z {z[k]:6.2f}"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", type=int, default=400)
    parser.add_argument("--nuts-samples", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    sbc(args.datasets, args.seed)
    mh_vs_nuts(args.seed, args.nuts_samples)


if __name__ == "__main__":
    main()
