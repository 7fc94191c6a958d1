"""Benchmark: adapting the sequence model to a new place from unlabelled streams, on one CPU core.

A fit of ``hbni_pyro.adapt`` on ``U`` unlabelled sequences of 30 frames, 6 classes in a skewed mix, simulated from
a sequence model whose class looks moved from an old place's by a shared scale and offset and a little per class
(what ``experiment=new_place`` fits, with its settings: 8 chains, 500 draws after 500 warm-up). Printed per ``U``:
CPU seconds of the fit (the floor: 120 s at the study's largest ``U``, 600), the share of sequences whose class it
recovers and the largest standardised error of a class mean. Beside it, the compiled class draw of the unlabelled
sequences against the torch one it replaced on the CPU, both timed in this process on the same sampler state
(the class draw was most of a fit's time).

Usage, from the repository root: ``python -m benchmarks.bench_adapt [--sizes 600 3000]``
"""

from __future__ import annotations

import argparse
import time

import torch

from hbni_infra.streams import torch_generator

M, FRAMES, STUDY_U, FLOOR_S = 6, 30, 600, 120.0
MIX = torch.tensor([0.3, 0.22, 0.16, 0.13, 0.11, 0.08])


def places(seed: int = 0) -> tuple:
    """An old place's posterior (every draw the same parameters) and a new place's parameters moved from it."""
    import hbni_pyro
    from hbni_pyro.distributions.prior import HyperPrior
    from hbni_pyro.posterior.posterior import posterior_from_samples
    from hbni_pyro.models.sequence.program import look_prior_mean
    from hbni_pyro.models.sequence import draw_prior

    g = torch_generator(seed)
    old = {k: v[0] for k, v in draw_prior(HyperPrior(), M, 1, g).items()}
    old["loc"] = look_prior_mean(M, 1.5)
    samples = {k: v.expand((1, 1) + v.shape).clone() for k, v in old.items()}
    posterior = posterior_from_samples(samples, torch.full((M,), 1 / M), HyperPrior(), "sequence")
    prior = hbni_pyro.ShiftPrior.from_posterior(posterior)
    new = dict(
        old, loc=0.85 * prior.anchor + 0.2 + prior.shift_sd * torch.randn(M, M - 1, generator=g, dtype=torch.float64)
    )
    return posterior, new, g


def streams(new: dict, size: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    from hbni_pyro import sample_sequences

    classes = torch.multinomial(MIX, size, replacement=True, generator=g)
    seqs = sample_sequences(new["loc"], new["between"], new["within"], classes, FRAMES, g, 0.6)
    return seqs.reshape(-1, M), torch.arange(size).repeat_interleave(FRAMES), classes


def fit_case(size: int) -> str:
    import hbni_pyro
    from hbni_infra.threads import single_thread

    posterior, new, g = places()
    obs, ids, classes = streams(new, size, g)
    with single_thread():
        cpu = time.process_time()
        fitted = hbni_pyro.adapt(posterior, obs, sequence_ids=ids, num_chains=8, progress=False)
        cpu = time.process_time() - cpu
    right = (fitted.label_probs.reshape(size, FRAMES, M)[:, 0].argmax(-1) == classes).double().mean()
    loc = fitted.draws()["loc"]
    z = ((loc.mean(0) - new["loc"]) / loc.std(0)).abs().max()
    floor = f"  (floor {FLOOR_S:.0f} s: {'met' if cpu <= FLOOR_S else 'MISSED'})" if size == STUDY_U else ""
    return f"U = {size:5d}: {cpu:6.1f} CPU s{floor}; classes recovered {right:.3f}; largest |z| of a class mean {z:.2f}"


def draw_case(size: int, repeats: int = 20) -> str:
    """The compiled class draw against the torch one, on one sampler state of ``size`` unlabelled sequences."""
    from hbni_pyro.fit import _stacked_stats
    from hbni_pyro.models import SequenceMetropolis
    from hbni_pyro.models.sequence.steps import draw_classes
    from hbni_infra.threads import single_thread

    posterior, new, g = places()
    obs, ids, _ = streams(new, size, g)
    kernel = SequenceMetropolis(num_chains=8, seed=1)
    kernel.setup(0, _stacked_stats(obs.unsqueeze(0), None, ids))
    times = {}
    with single_thread():
        draw_classes(kernel.state, kernel.stats, kernel.log_prior, g, compiled=True)  # compiled once
        for compiled in (True, False, True, False):  # interleaved
            start = time.process_time()
            for _ in range(repeats):
                draw_classes(kernel.state, kernel.stats, kernel.log_prior, g, compiled=compiled)
            times.setdefault(compiled, []).append((time.process_time() - start) / repeats)
    fast, slow = min(times[True]), min(times[False])
    return f"U = {size:5d}, 8 chains: compiled {1e3 * fast:6.2f} ms, torch {1e3 * slow:6.2f} ms per draw: {slow / fast:4.1f}x"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[STUDY_U, 3000], help="unlabelled sequences")
    args = parser.parse_args()
    print("[adapt] class draw of every unlabelled sequence, one core, best of 2 interleaved runs:")
    for size in args.sizes:
        print("  " + draw_case(size))
    print(f"[adapt] hbni_pyro.adapt, {M} classes, {FRAMES} frames a sequence, 8 chains x (500 + 500), one core:")
    for size in args.sizes:
        print("  " + fit_case(size), flush=True)


if __name__ == "__main__":
    main()
