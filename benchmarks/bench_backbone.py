"""EfficientNet-Lite0 on one CPU core: images per CPU-second of the backbone against its explicit-padding reference.

The reference runs every "SAME" convolution the plain way, in the same process: an explicitly padded copy of its
input, then torch's convolution (``SameConv2d._padded``), which for a 1x1 convolution takes torch's CPU path for
it. The backbone's own path convolves with even padding (and a crop under a stride) and runs 1x1 convolutions as
one matrix product (:class:`classifiers.backbone.SameConv2d`). Both score the same random 224 x 224 batch; the
largest difference of their ImageNet scores is printed beside the rates.

    .venv/bin/python benchmarks/bench_backbone.py [--images 32] [--batch-sizes 1 4 8] [--rounds 3]

Prints, per batch size, each path's images per CPU-second (the median of interleaved rounds) and their ratio.
"""

from __future__ import annotations

import argparse
import time
from unittest import mock

import torch

from classifiers.backbone import SameConv2d, load_backbone
from hbni_infra.streams import torch_generator


def rate(backbone, x: torch.Tensor, batch_size: int) -> float:
    """Images per CPU-second of one pass over ``x`` in chunks of ``batch_size`` on one torch thread."""
    cpu = time.process_time()
    backbone(x, batch_size=batch_size, threads=1)
    return x.shape[0] / (time.process_time() - cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=32)
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 4, 8])
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds; the median is reported")
    args = parser.parse_args()
    backbone = load_backbone()
    x = torch.randn(args.images, 3, 224, 224, generator=torch_generator(0))
    scores = backbone(x[:4])
    with mock.patch.object(SameConv2d, "forward", SameConv2d._padded):
        reference_scores = backbone(x[:4])
    diff = float((scores - reference_scores).abs().max())
    print(f"largest score difference: {diff:.2e} (scores up to {float(scores.abs().max()):.1f})")
    print(f"{'batch':>5s} {'backbone img/CPU-s':>19s} {'reference img/CPU-s':>20s} {'ratio':>6s}")
    for batch_size in args.batch_sizes:
        ours, theirs = [], []
        for _ in range(args.rounds):
            ours.append(rate(backbone, x, batch_size))
            with mock.patch.object(SameConv2d, "forward", SameConv2d._padded):
                theirs.append(rate(backbone, x, batch_size))
        a, b = sorted(ours)[len(ours) // 2], sorted(theirs)[len(theirs) // 2]
        print(f"{batch_size:5d} {a:19.1f} {b:20.1f} {a / b:5.2f}x")


if __name__ == "__main__":
    main()
