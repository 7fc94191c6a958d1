"""The 8-bit backbone against float32: CPU time per frame on one thread, and the classifier's accuracy on mission frames.

Two frame classifiers are trained as the mission trains its own (``experiments.steps.classification.train_classifier``
on the mission's training snapshots, crops and mirrors, seed 0), one with ``precision="float"`` and one with
``precision="int8"`` (calibrated on its training crops). Both classify the same rendered mission-condition
sequences (the mission's imaging conditions, a seed no training saw); a frame is right when its most probable
class is the object's. Accuracies carry standard errors over sequences (frames of one sequence are correlated);
the difference is paired by sequence. Then the CPU time per frame of the backbone alone and of the whole classifier
(:meth:`~classifiers.FrameClassifier.proba`: crop, backbone, head) on one torch thread, at batch 1 (a live camera)
and at the classifier's batch (4, what the experiments run), float32 and 8-bit interleaved in rounds in one process
(the median round); on a CPU beyond AVX2, once more in a child process whose oneDNN, MKL and ATen kernels are capped
at AVX2 (``ONEDNN_MAX_CPU_ISA``, ``MKL_ENABLE_INSTRUCTIONS``, ``ATEN_CPU_CAPABILITY``), the code a CPU without
AVX-512 runs (on this CPU's cores and caches).

    .venv/bin/python -m benchmarks.bench_int8 [--sequences 40] [--frames 30] [--rounds 5] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from classifiers import FrameClassifier, center_crop, class_columns
from classifiers.data import get_conditions, render_sequence
from decpomdp.domains.disaster_relief import CLASSES
from experiments.schemas import compose_settings
from experiments.steps.classification import train_classifier
from hbni_infra.streams import stream_seed

PRECISIONS = ("float", "int8")
AVX2 = {"ONEDNN_MAX_CPU_ISA": "AVX2", "MKL_ENABLE_INSTRUCTIONS": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"}


def train(precision: str, seed: int) -> FrameClassifier:
    """The mission's classifier (its settings those of ``experiment=mission``) in ``precision``."""
    settings = compose_settings([f"seed={seed}", f"classifier.precision={precision}"])
    st = settings.mission
    return train_classifier(
        settings.classifier, CLASSES, st.train_per_class, st.augment, stream_seed(seed, "train"), progress=False
    )


def accuracy(classifiers: dict[str, FrameClassifier], sequences: int, frames: int, seed: int) -> None:
    """Per-frame accuracy of each classifier on the same mission sequences, with standard errors over sequences."""
    conditions = get_conditions("mission", **compose_settings([f"seed={seed}"]).mission.overrides)
    hits = {p: np.zeros((len(CLASSES), sequences)) for p in classifiers}  # per-sequence accuracy
    agree = np.zeros((len(CLASSES), sequences))
    for c, name in enumerate(CLASSES):
        for s in range(sequences):
            seq = render_sequence(name, frames, conditions, seed=stream_seed(seed, "bench_int8", name), index=s)
            labels = {}
            for p, clf in classifiers.items():
                labels[p] = clf.proba(seq)[:, class_columns(clf, CLASSES)].argmax(-1).numpy()
                hits[p][c, s] = float((labels[p] == c).mean())
            agree[c, s] = float((labels["float"] == labels["int8"]).mean())
    n = len(CLASSES) * sequences
    print(
        f"mission frames: {n * frames} ({len(CLASSES)} classes x {sequences} sequences x {frames} frames), seed {seed}"
    )
    for p, h in hits.items():
        print(f"  {p:>5s} accuracy {h.mean():.4f} +- {h.std(ddof=1) / np.sqrt(n):.4f} (s.e. over sequences)")
    diff = (hits["int8"] - hits["float"]).ravel()
    print(f"  int8 - float {diff.mean():+.4f} +- {diff.std(ddof=1) / np.sqrt(n):.4f} (paired by sequence)")
    print(f"  same label on {agree.mean():.4f} of the frames")
    for c, name in enumerate(CLASSES):
        print(f"    {name:>14s}: float {hits['float'][c].mean():.3f}  int8 {hits['int8'][c].mean():.3f}")


def cpu_ms(run, count: int) -> float:
    """CPU milliseconds per frame of ``run()`` over ``count`` frames."""
    start = time.process_time()
    run()
    return (time.process_time() - start) * 1e3 / count


def latency(classifiers: dict[str, FrameClassifier], rounds: int, seed: int) -> None:
    """CPU ms per frame on one thread, float32 and 8-bit interleaved; the median of ``rounds`` rounds."""
    frames = render_sequence(CLASSES[0], 16, "mission", seed=seed)
    some = classifiers["float"]
    crops = np.stack([center_crop(im, some.backbone_.input_size, some.padding) for im in frames])
    networks = {p: clf._network() for p, clf in classifiers.items()}
    times: dict[tuple[str, str, int], list[float]] = {}
    for _ in range(rounds):
        for batch in (1, some.batch_size):
            chunks = [frames[i : i + batch] for i in range(0, len(frames), batch)]
            for p, clf in classifiers.items():
                net = networks[p]
                times.setdefault(("backbone", p, batch), []).append(
                    cpu_ms(lambda: net.scores(crops, batch, threads=1), len(crops))  # noqa: B023
                )
                times.setdefault(("classifier", p, batch), []).append(
                    cpu_ms(lambda: [clf.proba(chunk) for chunk in chunks], len(frames))  # noqa: B023
                )
    print(f"CPU ms per frame on one thread (median of {rounds} interleaved rounds, {len(frames)} frames each)")
    print("  backbone: uint8 crops to ImageNet scores; classifier: frames to probabilities (crop, backbone, head)")
    print(f"  {'what':>10s} {'batch':>5s} {'float32':>8s} {'int8':>8s} {'ratio':>6s}")
    for what in ("backbone", "classifier"):
        for batch in (1, some.batch_size):
            f, q = (float(np.median(times[(what, p, batch)])) for p in PRECISIONS)
            print(f"  {what:>10s} {batch:5d} {f:8.2f} {q:8.2f} {q / f:5.2f}x")


def cpu_features() -> str:
    """The x86 features the kernels choose among, as this CPU reports them."""
    flags = set()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        flags = set(next((ln for ln in cpuinfo.read_text().splitlines() if ln.startswith("flags")), "").split())
    found = [f for f in ("avx2", "avx512f", "avx512_vnni", "amx_int8") if f in flags]
    return ", ".join(found) or "none of avx2, avx512f, avx512_vnni, amx_int8"


def latency_on_avx2(classifiers: dict[str, FrameClassifier], rounds: int, seed: int) -> None:
    """:func:`latency` of the same saved classifiers in a child process whose kernels are capped at AVX2."""
    with tempfile.TemporaryDirectory() as folder:
        for p, clf in classifiers.items():
            clf.save(Path(folder) / f"{p}.safetensors")
        args = [sys.executable, "-m", "benchmarks.bench_int8", "--saved", folder, "--rounds", str(rounds)]
        out = subprocess.run(args, env=os.environ | AVX2, check=True, capture_output=True, text=True).stdout
    print("with the kernels capped at AVX2 (" + ", ".join(f"{k}={v}" for k, v in AVX2.items()) + "):")
    print("\n".join("  " + line for line in out.strip().splitlines()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=40, help="mission sequences per class")
    parser.add_argument("--frames", type=int, default=30, help="frames per sequence")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved timing rounds; the median is reported")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--saved", type=Path, help="time the classifiers saved in this folder, nothing else")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.saved is not None:
        saved = {p: FrameClassifier.load(args.saved / f"{p}.safetensors") for p in PRECISIONS}
        print(f"ATen kernels: {torch.backends.cpu.get_cpu_capability()}")
        latency(saved, args.rounds, args.seed)
        return
    classifiers = {p: train(p, args.seed) for p in PRECISIONS}
    print(f"CPU features: {cpu_features()}; ATen kernels: {torch.backends.cpu.get_cpu_capability()}")
    latency(classifiers, args.rounds, args.seed)
    if torch.backends.cpu.get_cpu_capability() == "AVX512":
        latency_on_avx2(classifiers, args.rounds, args.seed)
    accuracy(classifiers, args.sequences, args.frames, args.seed)


if __name__ == "__main__":
    main()
