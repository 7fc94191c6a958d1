"""Bag source benchmark: the same frames read from ROS bags and from a lossless image folder.

Rendered mission-condition frames of the six disaster-relief classes are written once as a folder of PNG
files (the reference: lossless, decoded by OpenCV) and as bags of one image topic: MCAP with raw ``bgr8``
images, MCAP with PNG ``CompressedImage`` messages, sqlite3 (raw) and ROS 1 (raw). In this process, each is
then read:

1. source only: every frame decoded (``stamped()``: header stamp, receive time);
2. end to end: the stream experiment's loop (:func:`experiments.studies.stream.stream_frames`: classification, the
   HBNI macro-observation process restarting after each macro-observation, no pictures), without and, for
   the MCAP bag, with the ROS output bag.

Each configuration runs ``--repeats`` times, interleaved with the folder's runs; the least CPU time per frame
is kept (CPU time: what this process spent, whatever else runs on the machine). Printed: CPU ms per frame
and the frame rate it allows, and the ratio of each source's throughput to the folder's (1.00: the same;
the acceptance is a bag within 10 % of the folder end to end, ratio >= 0.90).

Usage: ``python -m benchmarks.bench_bag_source [--frames 180] [--repeats 3] [--seed 0]``
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
from classifiers import FrameClassifier, class_columns
from classifiers.bags import write_image_bag
from classifiers.data import render_images, render_sequence
from classifiers.sources import open_source
from decpomdp.domains.disaster_relief import CLASSES
from experiments.studies.stream import Models, Settings, stream_frames
from hbni_infra.streams import stream_seed


def _models(seed: int) -> Models:
    images = [im for name in CLASSES for im in render_images(name, 10, "training", seed=seed)]
    clf = FrameClassifier(seed=seed, threads=1).fit(images, [name for name in CLASSES for _ in range(10)])
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
        num_chains=4,
        num_samples=300,
        warmup_steps=300,
        seed=seed,
        progress=False,
    )
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.HBNIFilter(posterior, temper=0.4), 0.95, 30)
    return Models(clf, process, list(CLASSES), 0.4)


def _sources(root: Path, frames: int, seed: int) -> dict[str, Path]:
    per_class = -(-frames // len(CLASSES))
    seed = stream_seed(seed, "clip")
    clip = np.concatenate([render_sequence(n, per_class, "mission", seed=seed) for n in CLASSES])[:frames]
    folder = root / "folder"
    folder.mkdir()
    for i, frame in enumerate(clip):
        cv2.imwrite(str(folder / f"{i:05d}.png"), frame)
    return {
        "image folder (PNG)": folder,
        "MCAP bag, bgr8": write_image_bag(root / "raw", clip),
        "MCAP bag, PNG compressed": write_image_bag(root / "png", clip, encoding="png"),
        "sqlite3 bag, bgr8": write_image_bag(root / "sqlite", clip, storage="sqlite3"),
        "ROS 1 bag, bgr8": write_image_bag(root / "ros1.bag", clip, storage="rosbag1"),
    }


def _read(path: Path) -> int:
    return sum(1 for _ in open_source(path).stamped())


def _stream(models: Models, path: Path, out: Path, bag: bool) -> int:
    settings = Settings(str(path), None, None, None, None, None, None, 0.95, 30, 8, (), False, bag=bag)
    return stream_frames(settings, models, out).frames


def _cpu_per_frame(fn) -> float:
    cpu = time.process_time()
    n = fn()
    return (time.process_time() - cpu) / n


def _table(title: str, costs: dict[str, float], reference: str) -> None:
    print(title)
    for name, cost in costs.items():
        ratio = costs[reference] / cost
        print(f"  {name:<40} {1e3 * cost:7.2f} ms CPU/frame  {1 / cost:7.1f} fps  throughput / folder {ratio:5.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=180)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    models = _models(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        sources = _sources(root, args.frames, args.seed)
        reference = next(iter(sources))
        print(f"[bag source] {args.frames} frames 320x240; best of {args.repeats} interleaved runs; 1 thread")
        read = {name: float("inf") for name in sources}
        stream = {name: float("inf") for name in sources}
        stream_bag_out, runs = float("inf"), 0
        for _ in range(args.repeats):
            for name, path in sources.items():
                read[name] = min(read[name], _cpu_per_frame(lambda: _read(path)))
            for name, path in sources.items():
                runs += 1
                stream[name] = min(
                    stream[name], _cpu_per_frame(lambda: _stream(models, path, root / f"r{runs}", False))
                )
            runs += 1
            raw = sources["MCAP bag, bgr8"]
            stream_bag_out = min(stream_bag_out, _cpu_per_frame(lambda: _stream(models, raw, root / f"r{runs}", True)))
        _table("source only (decode, stamps):", read, reference)
        stream["MCAP bag, bgr8 + output bag"] = stream_bag_out
        _table("end to end (classify, HBNI macro-observations):", stream, reference)
        worst = min(stream[reference] / cost for name, cost in stream.items() if name != reference)
        print(
            f"  worst bag / folder throughput end to end: {worst:.2f} ({'within' if worst >= 0.9 else 'NOT within'} 10 %)"
        )


if __name__ == "__main__":
    main()
