"""Benchmark: fitting HBNI at scale, and the per-frame filter update of every noise model.

Each case runs in its own subprocess, so its peak resident memory (``ru_maxrss``, which includes
the ~0.3 GB of an imported torch and Pyro) is its own. Printed per case: wall time, CPU time,
peak memory, and the floor. Wall times on a shared machine are inflated by the other jobs; the
CPU time of the process is the steadier figure.

1. Labelled fit of 1 000 000 x 10 outputs with default settings (``hbni.fit``: 16 chains,
   1000 draws after 500 warm-up): labelled outputs enter only through per-class counts and
   sums of log outputs, so the fit is one pass over the data plus iterations on ``M x M``
   statistics. Floors: 10 s and 1 GB. Also the confusion-aware and sequence-aware models on
   the same data (the sequence model with 10 000 sequences of 100 frames; floors 60 CPU s, 1 GB).
2. Unlabelled fit of 200 000 x 10 outputs with default settings: the class moves evaluate only
   each output's current and proposed class, run over the outputs in cache-sized blocks and
   rewrite the classes in place (no chains x outputs array is allocated per iteration, so the
   heap does not grow over the run); label frequencies are pooled over chains. On the CPU the class
   move, its statistics and the label counts are one compiled function, three branch-poor passes over
   each block (coins and proposals, acceptances, statistics). Floors: 60 CPU s, 1 GB peak.
3. Per-frame filter update (``HBNIFilter.update``, marginal over the posterior's draws) of every
   model on 6 classes, against the paper's filter in the same process. Floor: 2 ms.

Usage, from the repository root: ``python -m benchmarks.bench_fit_scale [--case all|labelled|unlabelled|filter]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import torch
from hbni_infra.streams import torch_generator

ROOT = Path(__file__).resolve().parents[1]
GB = 1024**3


def _peak_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _data(n: int, m: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    from hbni_pyro import sample_outputs

    g = torch_generator(seed)
    theta = torch.linspace(1.0, 20.0, m, dtype=torch.float64)
    classes = torch.arange(m).repeat_interleave(n // m)
    return sample_outputs(theta, classes, g).float(), classes


def case_fit(kind: str, model: str) -> dict:
    """One fit in this process; returns its timings and peak memory."""
    import hbni_pyro

    n = 1_000_000 if kind == "labelled" else 200_000
    obs, classes = _data(n, 10)
    ids = torch.arange(n) // 100 if hbni_pyro.noise_model(model).sequences else None
    if ids is not None:
        classes = classes[ids * 100]  # one label per sequence of 100 frames
    base = _peak_bytes()
    wall, cpu = time.perf_counter(), time.process_time()
    post = hbni_pyro.fit(obs, classes if kind == "labelled" else None, model=model, sequence_ids=ids, progress=False)
    return {
        "case": f"{kind} fit {n} x 10, {model}",
        "wall_s": time.perf_counter() - wall,
        "cpu_s": time.process_time() - cpu,
        "peak_gb": _peak_bytes() / GB,
        "data_gb": base / GB,
        "draws": post.num_chains * post.num_draws,
    }


def case_filter() -> list[dict]:
    """Per-frame update time of each model's filter (6 classes, 16 chains x 1000 draws, marginal)."""
    from hbni_pyro import HBNIFilter, HBNIPosterior, sample_outputs

    torch.set_num_threads(2)
    M, C, S = 6, 16, 1000
    g = torch_generator(0)
    theta = torch.linspace(1.0, 20.0, M, dtype=torch.float64) * torch.exp(
        0.2 * torch.randn(C, S, M, generator=g, dtype=torch.float64)
    )
    ones = torch.ones(C, S, dtype=torch.float64)
    beta = torch.exp(0.3 * torch.randn(C, S, M, M, generator=g, dtype=torch.float64)).masked_fill(
        torch.eye(M, dtype=torch.bool), 1.0
    )
    d = M - 1
    a = 0.3 * torch.randn(C, S, M, d, d, generator=g, dtype=torch.float64)
    b = 0.2 * torch.randn(C, S, d, d, generator=g, dtype=torch.float64)
    eye = torch.eye(d, dtype=torch.float64)
    posts = {
        "paper": HBNIPosterior(
            {"theta": theta, "kappa": ones, "gamma": ones}, torch.full((M,), 1 / M, dtype=torch.float64)
        ),
        "confusion": HBNIPosterior(
            {"theta": theta, "beta": beta, "kappa": ones, "gamma": ones, "beta_loc": 0 * ones, "beta_scale": ones},
            torch.full((M,), 1 / M, dtype=torch.float64),
            model="confusion",
        ),
        "sequence": HBNIPosterior(
            {
                "loc": torch.randn(C, S, M, d, generator=g, dtype=torch.float64),
                "between": a @ a.transpose(-1, -2) + 0.1 * eye,
                "between_mean": 0.1 * eye.expand(C, S, d, d),
                "between_pooling": ones,
                "within": b @ b.transpose(-1, -2) + 0.1 * eye,
            },
            torch.full((M,), 1 / M, dtype=torch.float64),
            model="sequence",
        ),
    }
    frames = sample_outputs(torch.full((M,), 5.0, dtype=torch.float64), torch.zeros(200, dtype=torch.long), g)
    out = []
    for name, post in posts.items():
        for draws in (None, 1000):
            f = HBNIFilter(post, num_draws=draws)
            for o in frames[:20]:  # warm caches
                f.update(o)
            f.reset()
            wall, cpu = time.perf_counter(), time.process_time()
            for o in frames:
                f.update(o)
            n = len(frames)
            out.append(
                {
                    "case": f"filter update, {name}, {f.draws[next(iter(f.draws))].shape[0]} draws",
                    "wall_ms": 1e3 * (time.perf_counter() - wall) / n,
                    "cpu_ms": 1e3 * (time.process_time() - cpu) / n,
                }
            )
    return out


def _run(args: list[str]) -> list[dict]:
    cmd = [sys.executable, "-m", "benchmarks.bench_fit_scale", "--worker", *args]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", choices=("all", "labelled", "unlabelled", "filter"), default="all")
    parser.add_argument("--worker", nargs="*", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        result = case_filter() if args.worker[0] == "filter" else [case_fit(*args.worker)]
        print(json.dumps(result))
        return
    jobs = []
    if args.case in ("all", "labelled"):
        jobs += [["labelled", model] for model in ("paper", "confusion", "sequence")]
    if args.case in ("all", "unlabelled"):
        jobs.append(["unlabelled", "paper"])
    if args.case in ("all", "filter"):
        jobs.append(["filter"])
    for job in jobs:
        for r in _run(job):
            _print_row(r)


def _print_row(r: dict) -> None:
    if "peak_gb" in r:
        floor = {
            "labelled fit 1000000 x 10, paper": "floor 10 s, 1 GB",
            "labelled fit 1000000 x 10, sequence": "floor 60 CPU s, 1 GB",
            "unlabelled fit 200000 x 10, paper": "floor 60 CPU s, 1 GB",
        }
        print(
            f"{r['case']:42s} wall {r['wall_s']:7.2f} s  cpu {r['cpu_s']:7.2f} s  peak {r['peak_gb']:.2f} GB "
            f"(after data and imports {r['data_gb']:.2f} GB)  {floor.get(r['case'], '')}",
            flush=True,
        )
    else:
        print(
            f"{r['case']:42s} wall {r['wall_ms']:7.3f} ms  cpu {r['cpu_ms']:7.3f} ms per frame  floor 2 ms", flush=True
        )


if __name__ == "__main__":
    main()
