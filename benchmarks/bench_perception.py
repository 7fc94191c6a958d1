"""Perception benchmark, one run: per-frame throughput and head training against scikit-learn.

1. Frames per second for backbone (the default: 8-bit on an x86-64 CPU) + SVM head + HBNI filter update, one
   frame at a time (the onboard setting; floor 20 fps, the paper's rate), and the HBNI update's share of the frame
   time.
2. Head training time, accuracy and log-loss of :class:`classifiers.OneVsOneSVC` against
   ``sklearn.svm.SVC(kernel="linear", probability=True)`` on the same standardised backbone
   features: trained on training-condition snapshots, tested on mission-condition snapshots
   (the perception study's setting).

Usage: ``python benchmarks/bench_perception.py [--frames 60] [--threads 2] [--seed 0]``
(``--threads`` is torch's global setting; the frame-rate part measures 1 and 2 backbone threads.)
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

import hbni_pyro
from classifiers import FrameClassifier, OneVsOneSVC
from classifiers.data import render_images, render_sequence
from hbni_infra.streams import stream_seed

VEHICLES = ("irobot", "quadrotor", "racecar")  # the classes of the paper's hardware study

FLOOR_FPS = 20.0


def _snapshots(n: int, conditions: str, seed: int) -> tuple[list[np.ndarray], np.ndarray]:
    images, labels = [], []
    for k, name in enumerate(VEHICLES):
        images += list(render_images(name, n, conditions, seed=seed))
        labels += [k] * n
    return images, np.array(labels)


def bench_frame_rate(clf: FrameClassifier, x_cal: torch.Tensor, y_cal: np.ndarray, frames: int, seed: int) -> None:
    posterior = hbni_pyro.fit(
        clf.proba_from_features(x_cal).double(),
        torch.as_tensor(y_cal),
        num_chains=8,
        num_samples=500,
        warmup_steps=300,
        seed=seed,
        progress=False,
    )
    filt = hbni_pyro.HBNIFilter(posterior, mode="marginal")
    per_class = frames // len(VEHICLES) + 1
    seq = np.concatenate(
        [render_sequence(name, per_class, "mission", seed=stream_seed(seed, "sequence")) for name in VEHICLES]
    )[:frames]
    print(
        f"[frame rate] {len(seq)} mission frames one at a time (crop, {clf.precision_} backbone, head, HBNI marginal "
        f"update over {filt.theta.shape[0]} draws)"
    )
    for threads in (1, 2):
        clf.threads = threads
        for frame in seq[:3]:  # warm-up
            filt.update(clf.proba(frame)[0].double())
        filt.reset()
        t_clf = t_filter = 0.0
        for frame in seq:
            t0 = time.perf_counter()
            p = clf.proba(frame)[0].double()
            t1 = time.perf_counter()
            filt.update(p)
            t2 = time.perf_counter()
            t_clf += t1 - t0
            t_filter += t2 - t1
        total = t_clf + t_filter
        fps = len(seq) / total
        print(
            f"  backbone threads={threads}: backbone+head {1e3 * t_clf / len(seq):.1f} ms/frame, "
            f"HBNI update {1e3 * t_filter / len(seq):.2f} ms/frame"
        )
        print(
            f"    throughput {fps:.1f} fps (floor {FLOOR_FPS:.0f} fps: {'met' if fps >= FLOOR_FPS else 'NOT met'}, "
            f"ratio to floor {fps / FLOOR_FPS:.2f}x); HBNI share of frame time {100 * t_filter / total:.2f} %"
        )


def bench_head(x_tr, y_tr, x_te, y_te, seed: int) -> None:
    from sklearn.metrics import accuracy_score, log_loss
    from sklearn.svm import SVC

    mean, sd = x_tr.double().mean(0), x_tr.double().std(0).clamp_min(1e-6)
    a, b = ((x_tr - mean) / sd).numpy(), ((x_te - mean) / sd).numpy()
    t0 = time.perf_counter()
    head = OneVsOneSVC(C=1.0, seed=seed).fit(a, y_tr)
    t_ours = time.perf_counter() - t0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        t0 = time.perf_counter()
        ref = SVC(kernel="linear", probability=True, C=1.0, random_state=seed).fit(a, y_tr)
        t_ref = time.perf_counter() - t0
    p, p_ref = head.predict_proba(b), ref.predict_proba(b)
    print(
        f"[head] {len(y_tr)} training-condition snapshots to train, {len(y_te)} mission-condition snapshots to test, "
        f"{a.shape[1]} features, 3 classes"
    )
    print(
        f"  train time: torch OvO SVC {t_ours:.2f} s, sklearn SVC {t_ref:.2f} s "
        f"(ratio ours/sklearn {t_ours / t_ref:.1f}x)"
    )
    acc, acc_ref = accuracy_score(y_te, head.predict(b)), accuracy_score(y_te, ref.predict(b))
    print(f"  accuracy: ours {acc:.3f}, sklearn {acc_ref:.3f}")
    print(f"  log-loss: ours {log_loss(y_te, p):.3f}, sklearn {log_loss(y_te, p_ref):.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--train-per-class", type=int, default=100)
    parser.add_argument("--test-per-class", type=int, default=60)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    train, y_tr = _snapshots(args.train_per_class, "training", args.seed)
    test, y_te = _snapshots(args.test_per_class, "mission", stream_seed(args.seed, "test"))
    oracle = FrameClassifier(seed=args.seed, precision="float")  # the head comparison on float32 features
    bench_head(oracle.features(train), y_tr, oracle.features(test), y_te, args.seed)
    clf = FrameClassifier(seed=args.seed).fit(train, [VEHICLES[k] for k in y_tr])  # the default backbone
    bench_frame_rate(clf, clf.features(test), y_te, args.frames, args.seed)


if __name__ == "__main__":
    main()
