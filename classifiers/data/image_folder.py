"""Read a user's images: labelled ``root/<class>/*.png`` folders, or a flat folder of frames.

Image files are ``.png``, ``.jpg``, ``.jpeg`` or ``.bmp``. A flat folder (images directly in
``root``, as a camera or a video export writes them) is read unlabelled, in name order with
numbers compared as numbers (``frame_2.png`` before ``frame_10.png``).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

__all__ = ["ImageFolder"]

_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")


class ImageFolder:
    """Images grouped by class folder, in sorted order; or the unlabelled frames of a flat folder.

    Attributes:
        classes: sorted class names (the sub-folders holding at least one image); empty for a
            flat folder.
        samples: ``(path, class index)`` pairs, sorted by class then file name; for a flat folder,
            ``(path, -1)`` in name order.
        labelled: whether the images come with classes (class folders) or not (a flat folder).

    Raises:
        FileNotFoundError: ``root`` is not a directory.
        ValueError: no images under ``root``, or both class folders and loose images (ambiguous).
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if self.root.is_file():
            raise NotADirectoryError(f"root: {str(self.root)!r} is a file, expected a folder of images")
        if not self.root.is_dir():
            raise FileNotFoundError(f"root: no such directory {str(self.root)!r}")
        folders = {}
        for d in sorted(p for p in self.root.iterdir() if p.is_dir()):
            files = _images(d)
            if files:
                folders[d.name] = files
        loose = _images(self.root)
        if folders and loose:
            raise ValueError(
                f"root: {str(self.root)!r} holds both <class>/ folders and loose images; "
                "expected one layout (class folders, or a flat folder of frames)"
            )
        if not folders and not loose:
            raise ValueError(
                f"root: {str(self.root)!r} has no images ({'/'.join(_EXTENSIONS)}), "
                "neither in <class>/ folders nor directly in it"
            )
        self.labelled = bool(folders)
        self.classes = list(folders)
        self.samples = [(f, k) for k, name in enumerate(self.classes) for f in folders[name]] or [
            (f, -1) for f in loose
        ]

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> tuple[np.ndarray, int]:
        """Image ``i`` as uint8 BGR ``(H, W, 3)`` and its class index (-1 in a flat folder)."""
        path, label = self.samples[i]
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"image {str(path)!r} could not be decoded")
        return img, label

    def load(self) -> tuple[list[np.ndarray], Tensor]:
        """All images (list of uint8 BGR arrays) and their class indices ``(N,)`` long (-1: unlabelled)."""
        pairs = [self[i] for i in range(len(self))]
        return [p[0] for p in pairs], torch.tensor([p[1] for p in pairs], dtype=torch.long)


def _natural_key(path: Path) -> list:
    """Sort key comparing the numbers inside a file name as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def _images(directory: Path) -> list[Path]:
    """Image files directly in ``directory``, in name order (numbers as numbers)."""
    return sorted((f for f in directory.iterdir() if f.is_file() and f.suffix.lower() in _EXTENSIONS), key=_natural_key)
