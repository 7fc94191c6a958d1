"""Stream benchmark: frames per second of ``experiment=stream`` end to end, decoding included.

A video of rendered mission-condition frames of the six disaster-relief classes is written once;
then, in this process, each configuration reads it from the start:

1. decoding only (the reference: OpenCV reading the file);
2. decoding + classification (crop, EfficientNet-Lite0, SVM head) at 1 and 2 backbone threads;
3. the stream experiment's own loop (:func:`experiments.studies.stream.stream_frames`): decoding,
   classification, the HBNI macro-observation process restarting after each macro-observation
   (a posterior of 8 chains x 500 draws, marginal filter) and the annotated video, at 1 and 2 threads.

Each line prints frames per second (wall), CPU seconds per frame, the ratio to the 20 fps floor
and the ratio of its time to decoding's. Wall rates on a shared machine are inflated by other
processes; the CPU time per frame is what the process itself spent.

Usage: ``python benchmarks/bench_stream.py [--frames 240] [--seed 0]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

import hbni_pyro
from classifiers import FrameClassifier, class_columns, classify_frames
from classifiers.data import render_images, render_sequence
from classifiers.sources import open_source
from decpomdp.domains.disaster_relief import CLASSES
from experiments.studies.stream import Models, Settings, stream_frames
from hbni_infra.streams import stream_seed

FLOOR_FPS = 20.0


def _models(seed: int) -> tuple[FrameClassifier, hbni_pyro.HBNIPosterior]:
    images = [im for name in CLASSES for im in render_images(name, 10, "training", seed=seed)]
    clf = FrameClassifier(seed=seed).fit(images, [name for name in CLASSES for _ in range(10)])
    order = class_columns(clf, CLASSES)
    calib = torch.cat(
        [
            clf.predict_proba(render_sequence(n, 10, "mission", seed=stream_seed(seed, "calibration")))[:, order]
            for n in CLASSES
        ]
    )
    posterior = hbni_pyro.fit(
        calib.double(),
        torch.arange(len(CLASSES)).repeat_interleave(10),
        num_chains=8,
        num_samples=500,
        warmup_steps=300,
        seed=seed,
        progress=False,
        class_names=list(CLASSES),
    )
    return clf, posterior


def _video(path: Path, frames: int, seed: int) -> Path:
    per_class = -(-frames // len(CLASSES))
    clip = np.concatenate([render_sequence(n, per_class, "mission", seed=stream_seed(seed, "clip")) for n in CLASSES])[
        :frames
    ]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (clip.shape[2], clip.shape[1]))
    for f in clip:
        writer.write(f)
    writer.release()
    return path


def _timed(fn) -> tuple[int, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    n = fn()
    return n, time.perf_counter() - wall, time.process_time() - cpu


def _line(name: str, n: int, wall: float, cpu: float, reference: float) -> None:
    fps = n / wall
    print(
        f"  {name:<44} {fps:6.1f} fps  {1e3 * cpu / n:6.1f} ms CPU/frame  floor ratio {fps / FLOOR_FPS:4.2f}x "
        f"({'met' if fps >= FLOOR_FPS else 'NOT met'})  time / decoding {wall / reference:5.1f}x"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    clf, posterior = _models(args.seed)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.HBNIFilter(posterior, temper=0.4), 0.95, 30)
    with tempfile.TemporaryDirectory() as tmp:
        video = _video(Path(tmp) / "clip.mp4", args.frames, args.seed)
        print(
            f"[stream] {args.frames} frames 320x240 mp4v; HBNI over {process.filter.theta.shape[0]} draws; "
            f"torch threads available {torch.get_num_threads()}"
        )
        n, wall, cpu = _timed(lambda: sum(1 for _ in open_source(video)))
        reference = wall
        _line("decode", n, wall, cpu, reference)
        for threads in (1, 2):
            clf.threads = threads
            n, wall, cpu = _timed(lambda: sum(1 for _ in classify_frames(open_source(video), clf, CLASSES)))
            _line(f"decode + classify (threads={threads})", n, wall, cpu, reference)
        for threads in (1, 2):
            clf.threads = threads
            out = Path(tmp) / f"run{threads}"
            settings = Settings(str(video), None, None, None, None, list(CLASSES), 0.4, 0.95, 30, 8, ("video",), False)
            streamed = stream_frames(settings, Models(clf, process, list(CLASSES), 0.4), out)
            _line(
                f"stream experiment loop (threads={threads})",
                streamed.frames,
                streamed.seconds,
                streamed.cpu_seconds,
                reference,
            )
        print(
            f"  macro-observations: {len(streamed.segments)}, mean frames {streamed.frames / len(streamed.segments):.1f}"
        )


if __name__ == "__main__":
    main()
