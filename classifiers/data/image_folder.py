"""Read a user's labelled images from ``root/<class>/*.png`` (also .jpg, .jpeg, .bmp)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

__all__ = ["ImageFolder"]

_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp")


class ImageFolder:
    """Images grouped by class folder, in sorted order.

    Attributes:
        classes: sorted class names (the sub-folders holding at least one image).
        samples: ``(path, class index)`` pairs, sorted by class then file name.

    Raises:
        FileNotFoundError: ``root`` is not a directory.
        ValueError: no class folder with images under ``root``.
    """

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise FileNotFoundError(f"root: no such directory {str(self.root)!r}")
        folders = {}
        for d in sorted(p for p in self.root.iterdir() if p.is_dir()):
            files = sorted(f for f in d.iterdir() if f.is_file() and f.suffix.lower() in _EXTENSIONS)
            if files:
                folders[d.name] = files
        if not folders:
            raise ValueError(f"root: {str(self.root)!r} has no <class>/ folders with {'/'.join(_EXTENSIONS)} images")
        self.classes = list(folders)
        self.samples = [(f, k) for k, name in enumerate(self.classes) for f in folders[name]]

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> tuple[np.ndarray, int]:
        """Image ``i`` as uint8 BGR ``(H, W, 3)`` and its class index."""
        path, label = self.samples[i]
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"image {str(path)!r} could not be decoded")
        return img, label

    def load(self) -> tuple[list[np.ndarray], Tensor]:
        """All images (list of uint8 BGR arrays) and their class indices ``(N,)`` long."""
        pairs = [self[i] for i in range(len(self))]
        return [p[0] for p in pairs], torch.tensor([p[1] for p in pairs], dtype=torch.long)
