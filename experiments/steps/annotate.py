"""Pictures of a macro-observation stream: annotated frames (a video, or a ROS bag's image topic) and a PNG strip.

:class:`FrameAnnotator` draws on every frame the classifier's top class, the filter's running belief
against the threshold, and the latest macro-observation; :class:`AnnotatedVideo` writes frames as an
``mp4v`` video (OpenCV).
:func:`strip_figure` is one picture of a whole stream: the deciding frame of some macro-observations
above a timeline of the filter's confidence, with each macro-observation's label marked where it
was emitted.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import matplotlib.pyplot as plt
import numpy as np
import torch
from torch import Tensor

from experiments.reports import figures
from hbni_pyro import Segment

_FONT = cv2.FONT_HERSHEY_SIMPLEX


class FrameAnnotator:
    """Draws on each frame the classifier's top class, the filter's running belief against the threshold, and the
    latest macro-observation.

    Args:
        classes: class names in the process's order.
        threshold: the process's confidence threshold (drawn on the belief bar).
        max_frames: the process's frame budget.
    """

    def __init__(self, classes: Sequence[str], threshold: float, max_frames: int) -> None:
        self.classes, self.threshold, self.max_frames = list(classes), threshold, max_frames
        self._size: tuple[int, int] | None = None
        self._latest = "macro-observation: none yet"

    def draw(self, segment: Segment, running: Tensor, images: Sequence[np.ndarray]) -> Iterator[np.ndarray]:
        """The annotated copies of a segment's frames ``images`` (uint8 BGR, all at the first frame's size),
        given the filter's ``running`` posterior ``(n, M)``."""
        top = segment.outputs.max(-1)
        belief = running.max(-1)
        for k, frame in enumerate(images):
            if k == len(images) - 1:
                flag = " (timed out)" if segment.timed_out else ""
                self._latest = (
                    f"macro-obs #{segment.index}: {segment.name} {segment.confidence:.2f} "
                    f"after {segment.frames_used} frames{flag}"
                )
            lines = (
                f"frame {segment.start + k}  CNN: {self.classes[int(top.indices[k])]} {float(top.values[k]):.2f}",
                f"filter: {self.classes[int(belief.indices[k])]} {float(belief.values[k]):.2f}  "
                f"({k + 1}/{self.max_frames} frames)",
            )
            yield self._draw(frame, lines, float(belief.values[k]))

    def _draw(self, frame: np.ndarray, lines: tuple[str, str], confidence: float) -> np.ndarray:
        if self._size is None:
            self._size = (frame.shape[1], frame.shape[0])
        img = frame if (frame.shape[1], frame.shape[0]) == self._size else cv2.resize(frame, self._size)
        img = img.copy()
        w, h = self._size
        scale = max(0.35, w / 800)
        row = int(22 * scale / 0.4)
        img[: 2 * row + 6] = (img[: 2 * row + 6] * 0.35).astype(np.uint8)
        img[h - row - 6 :] = (img[h - row - 6 :] * 0.35).astype(np.uint8)
        for i, text in enumerate(lines):
            cv2.putText(img, text, (6, row * (i + 1) - 4), _FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
        bar_x, bar_w = int(0.72 * w), int(0.25 * w)
        cv2.rectangle(img, (bar_x, row + 2), (bar_x + bar_w, 2 * row - 4), (90, 90, 90), -1)
        color = (80, 200, 80) if confidence >= self.threshold else (60, 160, 255)
        cv2.rectangle(img, (bar_x, row + 2), (bar_x + int(bar_w * confidence), 2 * row - 4), color, -1)
        mark = bar_x + int(bar_w * self.threshold)
        cv2.line(img, (mark, row), (mark, 2 * row - 2), (255, 255, 255), 1)
        cv2.putText(img, self._latest, (6, h - 8), _FONT, scale, (120, 255, 255), 1, cv2.LINE_AA)
        return img


class AnnotatedVideo:
    """An ``mp4v`` video of (annotated) frames, written frame by frame.

    Args:
        path: the video file to write (its directory is created).
        fps: frame rate of the written video.

    The video is written to a temporary name and renamed into place by :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike, fps: float) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self.path.with_name(f".{self.path.stem}.partial{self.path.suffix}")
        self.fps = float(fps)
        self._writer: cv2.VideoWriter | None = None
        self.frames_written = 0

    def write(self, img: np.ndarray) -> None:
        """Append a uint8 BGR frame (the first frame sets the video's size)."""
        if self._writer is None:
            size = (img.shape[1], img.shape[0])
            self._writer = cv2.VideoWriter(str(self._tmp), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, size)
            if not self._writer.isOpened():
                raise OSError(f"could not open {str(self._tmp)!r} for writing an mp4v video")
        self._writer.write(img)
        self.frames_written += 1

    def close(self) -> Path | None:
        """Finish the file and move it into place; returns its path (``None`` if no frame was written)."""
        if self._writer is None:
            return None
        self._writer.release()
        self._writer = None
        with open(self._tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(self._tmp, self.path)
        return self.path


def strip_figure(
    segments: Sequence[Segment],
    beliefs: Sequence[Tensor],
    thumbs: Sequence[np.ndarray],
    classes: Sequence[str],
    threshold: float,
    title: str,
    max_thumbs: int = 8,
) -> plt.Figure:
    """Deciding frames of up to ``max_thumbs`` evenly spread macro-observations above the stream's timeline.

    When there are more macro-observations than ``max_thumbs``, the title says how many are shown, and the
    timeline numbers the shown ones.

    Args:
        segments: the stream's macro-observations, in order.
        beliefs: each segment's running max confidence ``(n,)``.
        thumbs: each segment's deciding frame (uint8 BGR), same length as ``segments``.
    """
    n = len(segments)
    shown = sorted(set(np.linspace(0, n - 1, min(n, max_thumbs)).round().astype(int).tolist())) if n else []
    cols = max(len(shown), 1)
    fig = plt.figure(figsize=(max(9.0, 1.7 * cols + 1.6), 4.6))
    grid = fig.add_gridspec(2, cols, height_ratios=[1.0, 1.3], hspace=0.2, right=0.84)
    for j, i in enumerate(shown):
        ax = fig.add_subplot(grid[0, j])
        ax.imshow(cv2.cvtColor(thumbs[i], cv2.COLOR_BGR2RGB))
        s = segments[i]
        end = " end" if s.stream_ended else " t/o" if s.timed_out else ""
        ax.set_title(f"#{s.index} fr {s.start}-{s.end}\n{s.name}\n{s.confidence:.2f}{end}", fontsize=7)
        ax.axis("off")
    ax = fig.add_subplot(grid[1, :])
    for s, b in zip(segments, beliefs):
        x = np.arange(s.start, s.end + 1)
        ax.plot(x, b.numpy(), color=figures.CONFIDENCE_COLOR, lw=1)
        ax.scatter(
            [s.end],
            [s.confidence],
            color=figures.class_color(s.label),
            s=22,
            zorder=3,
            marker="x" if s.timed_out else "o",
        )
    for i in shown if len(shown) < n else []:
        ax.annotate(
            f"#{segments[i].index}",
            (segments[i].end, segments[i].confidence),
            xytext=(0, 5),
            textcoords="offset points",
            ha="center",
            fontsize=6,
        )
    for label, name in enumerate(classes):
        ax.scatter([], [], color=figures.class_color(label), s=22, label=name)
    ax.plot([], [], color=figures.CONFIDENCE_COLOR, lw=1, label="confidence")
    ax.axhline(threshold, ls="--", lw=1, color=figures.THRESHOLD_COLOR, label=f"threshold {threshold:g}")
    ax.set_xlabel("frame")
    ax.set_ylabel("filter confidence")
    ax.set_ylim(0, 1.02)
    thumbs_said = f"; frames shown for {len(shown)} of them, evenly spread" if len(shown) < n else ""
    ax.set_title(f"{n} macro-observations (o: threshold reached, x: timed out){thumbs_said}", fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="label", title_fontsize=7)
    fig.suptitle(title, fontsize=10)
    return fig


def thumbnail(frame: np.ndarray, width: int = 160) -> np.ndarray:
    """A copy of ``frame`` scaled to ``width`` pixels wide."""
    h, w = frame.shape[:2]
    return cv2.resize(frame, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


def max_confidence(running: Tensor) -> Tensor:
    """``(n,)`` the running posterior's maximum per frame."""
    return running.max(-1).values.to(torch.float64)
