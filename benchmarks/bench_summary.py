"""Benchmark: ``HBNIPosterior.summary()`` on 16 chains x 400 000 draws, in memory linear in the draws.

Each case runs in its own subprocess (Linux: the peak is read from ``/proc/self/status`` after resetting it); printed
per case: the wall time of ``summary()``, the process's peak resident memory while it ran (imported torch and Pyro
and the draws included: 5 sites of the paper's model on 3 classes, 256 MB at 16 x 400 000) and how much of it
``summary()`` added above what the process held before. The reference is the same
summary with pyro's ``effective_sample_size`` (what ``summary()`` used before), whose running minimum builds a
``(draws / 2)^2`` matrix: it runs at 8 000 draws per chain, where both are timed and the ratio printed; at
400 000 draws it would ask for 298 GB (2**30 bytes each; 320 GB of 10**9), so it is not run there. Floor: under 1 GB peak at 400 000 draws.

Usage, from the repository root: ``python -m benchmarks.bench_summary [--draws 400000] [--chains 16]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
MB = 1024**2
REFERENCE_DRAWS = 8000


def _status(field: str) -> int:
    """A memory figure of this process from ``/proc/self/status`` in bytes (``VmHWM``: peak, ``VmRSS``: now)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise RuntimeError(f"/proc/self/status has no {field}")


def _posterior(chains: int, draws: int):
    """A paper-model posterior of 3 classes whose draws are AR(1) series (lag-1 correlation 0.9, as slow MH
    chains give), written site by site into its tensors (no full-size temporaries)."""
    import numpy as np
    from scipy.signal import lfilter

    from hbni_pyro import HBNIPosterior
    from hbni_infra.streams import numpy_stream

    rng, rho = numpy_stream(0, "bench_summary"), 0.9
    theta = torch.empty(chains, draws, 3, dtype=torch.float64)
    kappa = torch.empty(chains, draws, dtype=torch.float64)
    gamma = torch.empty(chains, draws, dtype=torch.float64)
    for site in [theta[..., 0], theta[..., 1], theta[..., 2], kappa, gamma]:
        series = lfilter([(1 - rho**2) ** 0.5], [1.0, -rho], rng.standard_normal((chains, draws)), axis=1)
        site.copy_(torch.from_numpy(np.exp(series)))
    return HBNIPosterior({"theta": theta, "kappa": kappa, "gamma": gamma}, torch.full((3,), 1 / 3, dtype=torch.float64))


def case(chains: int, draws: int, reference: bool) -> dict:
    """``summary()`` in this process (with pyro's ESS when ``reference``): seconds, the process's peak memory
    while it ran (``VmHWM`` reset before it) and what it added to the memory held before it."""
    post = _posterior(chains, draws)
    if reference:
        import pyro.ops.stats

        import hbni_pyro.posterior.posterior as module

        module.effective_sample_size = lambda x: float(pyro.ops.stats.effective_sample_size(x, 0, 1))
    Path("/proc/self/clear_refs").write_text("5")  # resets the peak (VmHWM) to the memory held now
    held = _status("VmRSS")
    start = time.perf_counter()
    summary = post.summary()
    seconds = time.perf_counter() - start
    peak = _status("VmHWM")
    return {"seconds": seconds, "peak": peak, "added": max(peak - held, 0), "ess": summary["theta[0]"]["ess"]}


def run(chains: int, draws: int, reference: bool = False) -> dict:
    args = ["--case", json.dumps([chains, draws, reference])]
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.bench_summary", *args], cwd=ROOT, capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise RuntimeError(f"case {chains} x {draws} (reference={reference}) failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--chains", type=int, default=16)
    parser.add_argument("--draws", type=int, default=400_000)
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(case(*json.loads(args.case))))
        return
    ours_small = run(args.chains, REFERENCE_DRAWS)
    pyro_small = run(args.chains, REFERENCE_DRAWS, reference=True)
    ours = run(args.chains, args.draws)

    def line(name: str, r: dict, draws: int) -> str:
        return (
            f"{name:26s} {args.chains} x {draws:7d} draws: {r['seconds']:7.2f} s, peak {r['peak'] / MB:6.0f} MB "
            f"(summary added {r['added'] / MB:5.0f} MB), ESS theta[0] {r['ess']:9.0f}"
        )

    print(line("summary() (FFT ESS)", ours_small, REFERENCE_DRAWS))
    print(line("reference (pyro's ESS)", pyro_small, REFERENCE_DRAWS))
    print(
        f"ratio at {REFERENCE_DRAWS} draws: time reference / ours {pyro_small['seconds'] / ours_small['seconds']:.1f}x, "
        f"memory added reference / ours {pyro_small['added'] / max(ours_small['added'], MB):.0f}x; "
        f"same ESS: {abs(pyro_small['ess'] - ours_small['ess']) <= 1e-9 * ours_small['ess']}"
    )
    print(line("summary() (FFT ESS)", ours, args.draws))
    scale = (args.draws / REFERENCE_DRAWS) / (ours["seconds"] / ours_small["seconds"])
    quadratic = (args.draws // 2) ** 2 * 8 / 1024**3
    print(
        f"{args.draws} vs {REFERENCE_DRAWS} draws: {ours['seconds'] / ours_small['seconds']:.0f}x the time for "
        f"{args.draws / REFERENCE_DRAWS:.0f}x the draws (draws per second ratio {scale:.2f}); "
        f"pyro's ESS would allocate about {quadratic:.0f} GB there (not run)"
    )
    print(f"peak memory at {args.draws} draws: {ours['peak'] / MB:.0f} MB (floor: under 1024 MB)")


if __name__ == "__main__":
    main()
