"""CPU against CUDA, side by side in one run: CNN frames per second, exact-evaluation controllers per second,
and MH min-ESS per second of the unlabelled HBNI fit.

1. CNN: :class:`classifiers.Backbone` (EfficientNet-Lite0) on random 224 x 224 inputs; CPU in float32 on one
   thread (the package default), CUDA in float32 and float16, batches of 256. Scores come back to the CPU.
2. Exact evaluation: :func:`decpomdp.dpomdp.exact_value` of random 3-node joint controllers on the shipped
   ``dectiger`` (finite horizon 4) and ``dectiger`` discounted (gamma 0.9, infinite horizon).
3. MH: ``hbni_pyro.fit(..., device=)`` of 200 000 x 10 unlabelled outputs with default settings (16 chains,
   500 warm-up and 1000 kept iterations), min-ESS over the parameters per second of sampling
   (``info["seconds"]``), after a small warm-up fit on the same device (compilation, CUDA start-up).

Devices without CUDA print "n/a" in the CUDA column. The default (quick) sizes keep the CPU run short:
64 frames, 200 controllers, 20 000 x 10 outputs for the fit (the label says so); ``--full`` uses 512 frames,
2000 controllers and the 200 000 x 10 fit.

    .venv/bin/python benchmarks/bench_devices.py [--full]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable

import torch
from hbni_infra.streams import torch_generator

DEVICES = ("cpu", "cuda")


def _sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def _rate(run: Callable[[], object], count: int, device: str, repeats: int = 2) -> float:
    """Items per second of ``run`` (``count`` items), best of ``repeats`` after one warm-up call."""
    run()
    _sync(device)
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        _sync(device)
        best = min(best, time.perf_counter() - start)
    return count / best


def cnn_rates(frames: int) -> dict[str, float | None]:
    from classifiers import load_backbone

    x = torch.randn(frames, 3, 224, 224, generator=torch_generator(0))
    out: dict[str, float | None] = {}
    for device, dtype, batch in (("cpu", torch.float32, 8), ("cuda", torch.float32, 256), ("cuda", torch.float16, 256)):
        label = f"{device} {str(dtype).removeprefix('torch.')}"
        if device == "cuda" and not torch.cuda.is_available():
            out[label] = None
            continue
        net = load_backbone(device=device, dtype=dtype)
        out[label] = _rate(lambda net=net, batch=batch: net(x, batch_size=batch), frames, device)
    return out


def exact_rates(count: int) -> dict[str, dict[str, float | None]]:
    from decpomdp import random_controllers
    from decpomdp.dpomdp import TabularDecPOSMDP, exact_value

    ctrl = random_controllers(count, num_agents=2, num_nodes=3, num_actions=3, num_obs=2, generator=torch_generator(0))
    cases = {
        "dectiger h=4": (TabularDecPOSMDP.from_problem("dectiger", horizon=4), 4),
        "dectiger gamma=0.9 h=inf": (TabularDecPOSMDP.from_problem("dectiger", gamma=0.9, horizon=4), math.inf),
    }
    out: dict[str, dict[str, float | None]] = {}
    for name, (env, horizon) in cases.items():
        out[name] = {}
        for device in DEVICES:
            if device == "cuda" and not torch.cuda.is_available():
                out[name][device] = None
                continue
            out[name][device] = _rate(
                lambda env=env, horizon=horizon, device=device: exact_value(env, ctrl, horizon=horizon, device=device),
                count,
                device,
            )
    return out


def mh_rates(n: int) -> dict[str, tuple[float, float] | None]:
    """Per device, the unlabelled fit's (min-ESS per second of sampling, seconds of sampling)."""
    import hbni_pyro
    from hbni_pyro import sample_outputs

    m = 10
    theta = torch.linspace(1.0, 20.0, m, dtype=torch.float64)
    obs = sample_outputs(theta, torch.arange(m).repeat_interleave(n // m), torch_generator(0)).float()
    out: dict[str, tuple[float, float] | None] = {}
    for device in DEVICES:
        if device == "cuda" and not torch.cuda.is_available():
            out[device] = None
            continue
        hbni_pyro.fit(obs[:1000], progress=False, device=device, num_samples=20, warmup_steps=20)
        post = hbni_pyro.fit(obs, progress=False, device=device)
        seconds = post.info["seconds"]
        out[device] = (min(row["ess"] for row in post.summary().values()) / seconds, seconds)
    return out


def _cell(x: float | None) -> str:
    return "n/a" if x is None else f"{x:,.1f}" if x >= 10 else f"{x:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="full sizes (512 frames, 2000 controllers, 200 000 x 10)")
    args = parser.parse_args()
    frames, count, n = (512, 2000, 200_000) if args.full else (64, 200, 20_000)
    cuda = torch.cuda.get_device_name() if torch.cuda.is_available() else "none"
    print(f"torch {torch.__version__}, CUDA device: {cuda}, {'full' if args.full else 'quick'} sizes")

    print(f"\nCNN frames per second ({frames} frames, EfficientNet-Lite0 224 x 224)")
    for label, rate in cnn_rates(frames).items():
        print(f"  {label:<14} {_cell(rate):>12}")

    print(f"\nExact evaluation, controllers per second ({count} joint controllers, 3 nodes)")
    print(f"  {'case':<26} {'cpu':>12} {'cuda':>12}")
    for name, rates in exact_rates(count).items():
        print(f"  {name:<26} {_cell(rates['cpu']):>12} {_cell(rates['cuda']):>12}")

    print(f"\nMH min-ESS per second of sampling (unlabelled fit, {n} x 10 outputs, default settings)")
    rates = mh_rates(n)
    print(f"  {'':<18} {'cpu':>12} {'cuda':>12}")
    for label, i in (("min-ESS / s", 0), ("sampling seconds", 1)):
        cells = [_cell(None if rates[d] is None else rates[d][i]) for d in DEVICES]
        print(f"  {label:<18} {cells[0]:>12} {cells[1]:>12}")


if __name__ == "__main__":
    main()
