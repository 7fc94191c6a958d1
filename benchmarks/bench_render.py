"""Rendering and normalising mission frames: frames per CPU-second of the compiled pixel passes against their numpy
expressions, in this process.

The renderer's compositing, light, noise and quantisation (:mod:`classifiers.data.pixels`) and the backbone's input
normalisation (:func:`classifiers.preprocess.normalize`) each run as one compiled pass; the reference runs the numpy
expressions they replace (:func:`~classifiers.data.pixels.lit_numpy`, :func:`~classifiers.data.pixels.quantized_numpy`
and :func:`~classifiers.preprocess.normalized_numpy`). Both render the same 30-frame mission sequences of the six
disaster-relief classes on one thread (torch, BLAS and OpenCV, as the mission's workers run), and the bytes are
compared.

    .venv/bin/python benchmarks/bench_render.py [--sequences 2] [--rounds 3]

Prints frames per CPU-second of each path (the median of interleaved rounds) and their ratio, for rendering and for
normalising, and whether the outputs are equal.
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import numpy as np
import torch

from classifiers.backbone import load_backbone
from classifiers.data import render as render_module
from classifiers.data import render_sequence
from classifiers.data.pixels import lit_numpy, quantized_numpy
from classifiers.preprocess import center_crop, normalize, normalized_numpy
from decpomdp.domains.disaster_relief import CLASSES
from hbni_infra.threads import single_thread


def _normalize_numpy(crops: np.ndarray, mean, std) -> torch.Tensor:
    """``normalize`` on :func:`~classifiers.preprocess.normalized_numpy` (the reference)."""
    x = normalized_numpy(crops, np.asarray(mean, np.float32), 1.0 / np.asarray(std, np.float32))
    return torch.from_numpy(x).permute(0, 3, 1, 2)


def _render(sequences: int) -> np.ndarray:
    """Frames ``(6 * sequences * 30, H, W, 3)`` of mission sequences of every class."""
    return np.concatenate(
        [render_sequence(name, 30, "mission", seed=0, index=i) for name in CLASSES for i in range(sequences)]
    )


def _timed(fn, *args):
    cpu = time.process_time()
    out = fn(*args)
    return out, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=2, help="sequences per class")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds; the median is reported")
    args = parser.parse_args()
    with single_thread():
        _compare(args.sequences, args.rounds)


def _compare(sequences: int, rounds: int) -> None:
    backbone = load_backbone()
    _render(1)  # compiles (or loads) the passes
    rates: dict[str, list[float]] = {"render": [], "render_ref": [], "normalize": [], "normalize_ref": []}
    equal = True
    for _ in range(rounds):
        frames, seconds = _timed(_render, sequences)
        with mock.patch.multiple(render_module.pixels, lit=lit_numpy, quantized=quantized_numpy):
            reference, ref_seconds = _timed(_render, sequences)
        rates["render"].append(len(frames) / seconds)
        rates["render_ref"].append(len(frames) / ref_seconds)
        equal &= bool(np.array_equal(frames, reference))
        crops = np.stack([center_crop(f, backbone.input_size) for f in frames])
        x, seconds = _timed(normalize, crops, backbone.mean, backbone.std)
        x_ref, ref_seconds = _timed(_normalize_numpy, crops, backbone.mean, backbone.std)
        rates["normalize"].append(len(crops) / seconds)
        rates["normalize_ref"].append(len(crops) / ref_seconds)
        equal &= bool(torch.equal(x, x_ref))
    median = {k: sorted(v)[len(v) // 2] for k, v in rates.items()}
    print(f"{len(frames)} mission frames a round, {rounds} rounds; outputs equal: {equal}")
    print(f"{'stage':>9s} {'compiled frames/CPU-s':>22s} {'numpy frames/CPU-s':>19s} {'ratio':>6s}")
    for stage in ("render", "normalize"):
        a, b = median[stage], median[f"{stage}_ref"]
        print(f"{stage:>9s} {a:22.1f} {b:19.1f} {a / b:5.2f}x")


if __name__ == "__main__":
    main()
