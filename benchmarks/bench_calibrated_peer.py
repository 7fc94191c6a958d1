"""HBNI against the calibrated peer (per-frame calibration + SSBF), on photographs and in the main job.

1. Photographs (the ``noise_models`` study's photograph condition: six photographs, a moving camera, dim
   drifting light, blur, noise and an occluder): for each seed, every filter fitted on the same labelled
   calibration sequences and run at threshold 0.95 with a 30-frame budget on the held-out sequences: HBNI's
   default (the sequence model, stopping at the confidence that keeps the 0.95 promise on calibration
   sequences held out of its fit), the sequence model stopping at 0.95 itself, the calibrated peer (the matrix
   form of Dirichlet calibration or temperature scaling, then SSBF with its evidence weight fitted on the
   calibration sequences) and SSBF on raw outputs. Then the acceptance checks of the default against the peer.
2. The main job: for each seed the newest completed ``experiment=mission`` run under ``outputs/`` (``--run``
   runs them first, one after the other): planned, greedy and executed values of every policy, each process on
   the held-out streams of the closed loop, the closed-loop checks, and the run's wall time.

Usage: ``python -m benchmarks.bench_calibrated_peer [--seeds 0 1 2] [--run] [--skip-photos] [--skip-mission]``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

import hbni_pyro
from hbni_pyro import threshold_checks

THRESHOLD = 0.95
ROWS = {
    "default": "HBNI default (sequence model, calibrated stop)",
    "sequence": "HBNI sequence model, stop at 0.95",
    "calibrated": "calibrated (matrix) + SSBF",
    "calibrated_temperature": "calibrated (temperature) + SSBF",
    "ssbf": "SSBF on raw outputs",
}
POLICIES = ("perfect", "hbni", "calibrated", "ssbf", "max_of_mean")


def photo_filters(seed: int) -> tuple[dict, dict, tuple]:
    """Every filter of :data:`ROWS` fitted on the photographs' calibration sequences of ``seed``, HBNI's stop, and
    the held-out ``(streams, truth)``."""
    from experiments.runs.clock import StageClock
    from experiments.schemas import compose_settings
    from experiments.steps.condition_outputs import photo_outputs
    from experiments.steps.noise import fit_labelled
    from experiments.studies.noise_models import held_out_stops

    settings = compose_settings(["experiment=noise_models", f"seed={seed}", "progress=false"])
    scratch = Path(os.environ.get("TMPDIR", "/tmp")) / "bench_calibrated_peer"
    calib, held = photo_outputs(settings, StageClock("noise_models", settings.progress), scratch)
    C, _, F, M = calib.shape
    cs, ct = calib.reshape(-1, F, M), torch.arange(C).repeat_interleave(calib.shape[1])
    hs, ht = held.reshape(-1, F, M), torch.arange(C).repeat_interleave(held.shape[1])
    posterior = fit_labelled(calib, settings.hbni, seed, False, model="sequence")
    hbni = hbni_pyro.make_filter("hbni", posterior)
    stop = held_out_stops(calib, settings)[THRESHOLD]
    labels = torch.arange(C).view(-1, 1, 1).expand(calib.shape[:3])
    filters = {"default": hbni, "sequence": hbni, "ssbf": hbni_pyro.make_filter("ssbf", num_classes=M)}
    for kind, key in (("matrix", "calibrated"), ("temperature", "calibrated_temperature")):
        peer = hbni_pyro.make_filter("calibrated", calibration=hbni_pyro.fit_frame_calibration(calib, labels, kind))
        filters[key] = peer.tempered(hbni_pyro.fit_temper(peer, cs, ct).temper)
    return filters, {"default": {THRESHOLD: stop}}, (hs, ht, F)


def photographs(seeds: list[int]) -> None:
    print(f"[photographs] threshold {THRESHOLD}, 30-frame budget, held-out sequences (s.e. after ±)")
    print("| seed | filter | stop | right when it emits | right | mean frames | timeouts |")
    print("|---|---|---|---|---|---|---|")
    checks = []
    for seed in seeds:
        filters, stops, (streams, truth, frames) = photo_filters(seed)
        rows = {}
        for key, f in filters.items():
            row = threshold_checks(f, streams, truth, [THRESHOLD], frames, stops=stops.get(key))[f"{THRESHOLD:g}"]
            rows[key] = row
            stop = row.get("stop", THRESHOLD)
            temper = f" (evidence weight {f.temper:g})" if key.startswith("calibrated") else ""
            print(
                f"| {seed} | {ROWS[key]}{temper} | {stop:g} | {row['emitted_accuracy']:.3f} ± "
                f"{row['emitted_stderr']:.3f} | {row['overall_accuracy']:.3f} | {row['mean_frames']:.2f} ± "
                f"{row['frames_stderr']:.2f} | {row['timeout_rate']:.3f} |"
            )
        checks.append((seed, rows["default"], rows["calibrated"]))
    print()
    for seed, a, b in checks:
        print(
            f"seed {seed}: default right when it emits {a['emitted_accuracy']:.3f} + s.e. {a['emitted_stderr']:.3f} "
            f">= {THRESHOLD}: {_yes(a['emitted_accuracy'] + a['emitted_stderr'] >= THRESHOLD)}; frames over the "
            f"peer's {a['mean_frames'] / b['mean_frames']:.2f} <= 1.5: {_yes(a['mean_frames'] <= 1.5 * b['mean_frames'])}; "
            f"timeouts {a['timeout_rate']:.3f} <= 0.10: {_yes(a['timeout_rate'] <= 0.10)}"
        )


def mission_runs(seeds: list[int], run: bool) -> dict[int, Path]:
    from experiments import latest_run
    from experiments.runs.paths import outputs_root

    found = {}
    for seed in seeds:
        if run:
            start = time.perf_counter()
            cmd = [sys.executable, "-m", "experiments.run", f"seed={seed}", "progress=false"]
            subprocess.run(cmd, check=True, capture_output=True)
            print(f"[main job] seed {seed} ran in {time.perf_counter() - start:.0f} s wall", file=sys.stderr)
        runs = sorted(
            p
            for p in (outputs_root() / "mission").glob("*")
            if (p / "metrics.json").is_file() and f"seed: {seed}\n" in _read(p / ".hydra" / "config.yaml")
        )
        if runs:
            found[seed] = runs[-1]
    if not found:
        latest_run("mission")  # raises, saying how to make one
    return found


def mission(seeds: list[int], run: bool) -> None:
    runs = mission_runs(seeds, run)
    print("[main job] values (± rollout s.e.): planned / greedy controller / executed in closed loop")
    print("| seed | policy | planned | greedy | executed | executed / perfect's executed |")
    print("|---|---|---|---|---|---|")
    lines = []
    for seed, path in runs.items():
        m = json.loads((path / "metrics.json").read_text())
        v = m["variants"]
        perfect = v["perfect"]["executed"]["value"]
        for name in POLICIES:
            if name not in v:
                continue
            r = v[name]
            print(
                f"| {seed} | {name} | {r['value']:.3f} ± {r['stderr']:.3f} | {r['greedy']['value']:.3f} | "
                f"{r['executed']['value']:.3f} ± {r['executed']['stderr']:.3f} | {r['executed']['value'] / perfect:.3f} |"
            )
        stages = m.get("stage_seconds", {})
        wall, cpu = sum(t["wall"] for t in stages.values()), m.get("cpu_seconds", {})
        lines.append((seed, m, wall, cpu))
    print()
    print("[main job] each process on the held-out streams of the closed loop (threshold 0.95, 30-frame budget)")
    print("| seed | process | stop | streams | right when it emits | mean frames | timeouts |")
    print("|---|---|---|---|---|---|---|")
    for seed, m, _, _ in lines:
        for name in POLICIES[1:]:
            h = m["variants"].get(name, {}).get("held_out_process")
            if h:
                right = (
                    "none emitted"
                    if h["emitted_accuracy"] is None
                    else f"{h['emitted_accuracy']:.3f} ± {h['emitted_stderr']:.3f}"
                )
                print(
                    f"| {seed} | {name} | {h['stop']:g} | {h['streams']} | {right} | {h['mean_frames']:.2f} ± "
                    f"{h['frames_stderr']:.2f} | {h['timeout_rate']:.3f} |"
                )
    print()
    for seed, m, wall, cpu in lines:
        acc = m["closed_loop"]["acceptance"]
        keys = (
            "hbni_honest_on_held_out",
            "hbni_frames_over_calibrated",
            "hbni_frames_at_most_1.5x_calibrated",
            "hbni_timeouts_at_most_0.1",
            "hbni_executed_over_calibrated",
            "hbni_executed_at_least_calibrated",
            "hbni_executed_over_perfect",
            "hbni_executed_at_least_98pct_perfect",
        )
        shown = ", ".join(f"{k} {_fmt(acc.get(k))}" for k in keys)
        print(
            f"seed {seed}: {shown}; main process {wall:.0f} s wall, "
            f"{cpu.get('main', math.nan):.0f} s CPU (+{cpu.get('workers', math.nan):.0f} s in bank workers)"
        )


def _read(path: Path) -> str:
    return path.read_text() if path.is_file() else ""


def _fmt(value) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def _yes(ok: bool) -> str:
    return "yes" if ok else "NO"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--run", action="store_true", help="run the main job for each seed first")
    parser.add_argument("--skip-photos", action="store_true")
    parser.add_argument("--skip-mission", action="store_true")
    args = parser.parse_args()
    if not args.skip_photos:
        photographs(args.seeds)
        print()
    if not args.skip_mission:
        mission(args.seeds, args.run)


if __name__ == "__main__":
    main()
