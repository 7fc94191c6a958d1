"""Benchmark: the full filtering_error study, and the batched HBNI filter against a per-frame scipy loop.

1. Runs ``experiments.studies.filtering_error.run`` at the issue's full settings (2000 trials x 50
   lengths x 5 methods x 4 training sizes, 20 training sets per size, every MH fit through
   ``hbni_pyro.fit_many``) and prints its wall time. Floor: under 2 minutes on 2 cores.
2. Times the batched marginal HBNI filter (1000 posterior draws) on all 2000 x 50 trial frames
   and a reference that updates one frame at a time, calling ``scipy.stats.dirichlet.logpdf``
   for every (draw, class) and combining with ``scipy.special.logsumexp``. The reference runs
   on a few frames only and its per-frame rate is extrapolated; both rates and their ratio are
   printed (floor: 100x). The two are checked to agree on those frames first.

Usage: ``python benchmarks/bench_filtering.py [--reference-frames 6] [--seed 0]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.special
import scipy.stats
import torch

from experiments.schemas import compose_settings
from experiments.studies.filtering_error import run as run_study
from hbni_pyro import HBNIFilter, HBNIPosterior, sample_outputs
from hbni_infra.streams import torch_generator

STUDY_FLOOR_SECONDS = 120.0
RATIO_FLOOR = 100.0


def reference_filter(obs: np.ndarray, theta: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Per-frame loop: ``obs (N, M)`` -> class posterior after each frame ``(N, M)``."""
    S, M = theta.shape
    loglik = np.zeros((S, M))  # running sum over frames of log Dir(o_i; theta_m^(s) e_m + 1)
    out = []
    for o in obs:
        for s in range(S):
            for m in range(M):
                alpha = np.ones(M)
                alpha[m] += theta[s, m]
                loglik[s, m] += scipy.stats.dirichlet.logpdf(o, alpha)
        log_post = np.log(prior) + scipy.special.logsumexp(loglik, axis=0) - np.log(S)
        out.append(np.exp(log_post - scipy.special.logsumexp(log_post)))
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference-frames", type=int, default=6, help="frames the scipy reference filters")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    settings = compose_settings(["experiment=filtering_error", "progress=false", f"seed={args.seed}"])
    s, fit = settings.study, settings.hbni.fit
    print(
        f"filtering_error study: {s.num_trials} trials x N = 1..{s.max_len} x 5 methods x training sizes "
        f"{list(s.training_sizes)} ({s.num_training_sets} MH fits each: {fit.num_chains} chains, "
        f"{fit.warmup_steps} + {fit.num_samples} steps), HBNI mode {settings.hbni.filter.mode}, "
        f"torch threads {torch.get_num_threads()}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        start, cpu = time.perf_counter(), time.process_time()
        metrics = run_study(settings, Path(tmp))
        study_seconds, study_cpu = time.perf_counter() - start, time.process_time() - cpu
        fit_seconds = sum(f["seconds"] for f in metrics["fits"].values())
        posterior = HBNIPosterior.load(Path(tmp) / "posterior_train15_set0.safetensors")
    print(
        f"  full study: {study_seconds:.1f} s wall, {study_cpu:.1f} s CPU over all threads (MH fits {fit_seconds:.1f} s wall)"
        f"   floor < {STUDY_FLOOR_SECONDS:.0f} s: "
        f"{'PASS' if study_seconds < STUDY_FLOOR_SECONDS else 'FAIL'}"
    )
    for size, cross in metrics["crossing_n"].items():
        print(
            f"  training {size:>3}: N at error <= 5% / 1% / 0.5%: "
            + ", ".join(f"{m} {'/'.join(str(v) for v in c.values())}" for m, c in cross.items())
        )

    filt = HBNIFilter(posterior, "marginal", num_draws=1000)
    g = torch_generator(args.seed)
    trials, length = int(s.num_trials), int(s.max_len)
    truth = torch.randint(3, (trials,), generator=g)
    obs = sample_outputs(
        torch.tensor(list(s.true_theta), dtype=torch.float64), truth[:, None].expand(trials, length), g
    )
    start = time.perf_counter()
    batched = filt.run(obs)
    batched_rate = trials * length / (time.perf_counter() - start)

    frames = args.reference_frames
    start = time.perf_counter()
    ref = reference_filter(obs[0, :frames].numpy(), filt.theta.numpy(), filt.class_prior.numpy())
    reference_rate = frames / (time.perf_counter() - start)
    np.testing.assert_allclose(batched[0, :frames].numpy(), ref, rtol=1e-8, atol=1e-12)
    ratio = batched_rate / reference_rate
    print(f"HBNI marginal filter, {filt.theta.shape[0]} posterior draws, M = {filt.num_classes}:")
    print(f"  batched run over {trials} x {length} frames: {batched_rate:,.0f} frame updates/s")
    print(
        f"  scipy.stats.dirichlet.logpdf per-frame loop ({frames} frames, extrapolated): {reference_rate:,.2f} frame updates/s"
    )
    print(f"  ratio: {ratio:,.0f}x   floor >= {RATIO_FLOOR:.0f}x: {'PASS' if ratio >= RATIO_FLOOR else 'FAIL'}")


if __name__ == "__main__":
    main()
