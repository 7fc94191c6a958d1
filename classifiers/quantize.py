"""EfficientNet-Lite0 in 8-bit integers on the CPU: post-training static quantization, calibrated on images.

The float network (batch norms folded into the convolutions) becomes:

- weights: int8, symmetric, one scale per output channel (``max |w| / 127``);
- activations: uint8, one affine range per tensor, measured on calibration images (:func:`calibrate`): the
  inputs of the dense convolutions (the stem, every 1x1) are kept in 7 bits (``0..127``), the inputs of the
  depthwise convolutions in 8 bits (see "CPUs" below);
- ReLU6 and the activation grid's range as the convolution's clip, the residual sum as its ``sum`` post-op (then
  clipped to the grid's levels), the head convolution written in float32; the global average pool and the
  1000-way linear layer run in float32 on its output.

The convolutions are oneDNN's integer kernels (``torch.ops.onednn``, the ones torch's x86 inductor path
lowers to) on plain ``uint8``/``int8`` tensors with explicit scales: no quantized tensor dtypes.

"SAME" padding: TensorFlow pads a stride-2 convolution one pixel more at the bottom/right, which oneDNN's
symmetric padding cannot express. The network runs on the image mirrored in both axes with every kernel
mirrored, where that padding is at the top/left and equals the symmetric ``k // 2`` padding (the extra bottom/right
row and column are never read: the input sides are even, the kernels odd); the pool at the end does not see the
mirroring. The outputs are those of the unmirrored network.

CPUs: oneDNN needs an x86-64 CPU with AVX2 at least, and picks AVX2, AVX-512 (VNNI) or AMX kernels at run time.
AVX2 has no 8-bit dot-product instruction: its kernels add pairs of ``uint8 x int8`` products in saturating
16-bit lanes (``vpmaddubsw``), which overflow for 8-bit inputs (``2 * 255 * 127 > 32767``); with 7-bit
inputs (``2 * 127 * 127 < 32767``) every kernel sums exactly in int32, so the same integers come out of every
dense convolution on every x86 CPU. The depthwise kernels widen to int32 first and take 8 bits. What can differ
between CPU families is the float rounding of the final rescaling (one step of the 8-bit grid, rarely).
"""

from __future__ import annotations

import functools
import math
import platform
import threading
from dataclasses import dataclass
from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from classifiers.backbone import Backbone, EfficientNetLite0
from hbni_infra.numba_cache import use_cache_dir
from hbni_infra.threads import torch_threads

use_cache_dir()  # before any cached function is decorated

from numba import njit  # noqa: E402

__all__ = ["Calibration", "Calibrator", "Int8Backbone", "calibrate", "int8_unavailable", "point_names"]

_DENSE_LEVELS = 127  # 7-bit inputs of the dense (stem, 1x1) convolutions: no 16-bit saturation on AVX2
_DEPTHWISE_LEVELS = 255  # 8-bit inputs of the depthwise convolutions (their kernels widen to int32 first)
_WEIGHT_LEVELS = 127  # symmetric int8 weights in -127..127
_INPUT_SCALE, _INPUT_ZERO = 1 / 64, 63  # the stem's 7-bit input: (pixel - 127) / 128 on a 1/64 grid (pixels / 2)
_CLIPS = torch.linspace(1.0, 0.3, 15).tolist()  # fractions of the observed range tried by the error search


@dataclass(frozen=True)
class _Layer:
    """One convolution of the network in run order, named for the activation it writes (:func:`point_names`):
    ``act`` is what follows it (``"relu6"``, ``"none"``, or ``"add"``: plus its block's input); ``opens`` says
    whether it reads a block's input."""

    name: str
    conv: torch.nn.Conv2d
    act: str
    opens: bool = False


def _layers(net: EfficientNetLite0) -> list[_Layer]:
    """The convolutions of a (fused) Lite0 in run order."""
    layers = [_Layer("stem", net._conv_stem, "relu6")]
    for i, block in enumerate(net._blocks):
        if block.expand != 1:
            layers.append(_Layer(f"{i}.expand", block._expand_conv, "relu6", opens=True))
        layers.append(_Layer(f"{i}.depthwise", block._depthwise_conv, "relu6", opens=block.expand == 1))
        layers.append(_Layer(f"{i}.project", block._project_conv, "add" if block.skip else "none"))
    layers.append(_Layer("head", net._conv_head, "relu6"))
    return layers


def point_names(net: EfficientNetLite0) -> list[str]:
    """The quantized activations (the outputs of every convolution but the head's, which stays float32)."""
    return [layer.name for layer in _layers(net)[:-1]]


def _levels(layers: list[_Layer], i: int) -> int:
    """Levels of the activation written by ``layers[i]``: 8 bits when a depthwise convolution reads it."""
    return _DEPTHWISE_LEVELS if layers[i + 1].conv.groups > 1 else _DENSE_LEVELS


def _float_forward(net: EfficientNetLite0, x: Tensor, seen: Callable[[str, Tensor], None] | None = None) -> Tensor:
    """``net(x)`` written layer by layer, passing every activation of :func:`point_names` to ``seen(name, t)``."""
    h = block_in = x
    for layer in _layers(net):
        if layer.opens:
            block_in = h
        y = layer.conv(h)
        if layer.act == "relu6":
            y = F.relu6(y)
        elif layer.act == "add":
            y = y + block_in
        if seen is not None and layer.name != "head":
            seen(layer.name, y)
        h = y
    return net._fc(h.mean(dim=(2, 3)))


# ---- calibration ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Calibration:
    """The affine 8-bit grid of every quantized activation: ``value = scale * (q - zero_point)``.

    Attributes:
        scales: ``(P,)`` float64, one per name of :func:`point_names`, in that order.
        zero_points: ``(P,)`` int64, within each activation's levels.
    """

    scales: Tensor
    zero_points: Tensor

    def __post_init__(self) -> None:
        s, z = self.scales, self.zero_points
        if not isinstance(s, Tensor) or not isinstance(z, Tensor) or s.ndim != 1 or z.shape != s.shape:
            raise ValueError("calibration: expected scales and zero_points of one shape (P,)")
        if s.dtype != torch.float64 or z.dtype != torch.int64:
            raise ValueError(f"calibration: expected float64 scales and int64 zero points, got {s.dtype}, {z.dtype}")
        if not bool(torch.isfinite(s).all() and (s > 0).all()) or not bool(((z >= 0) & (z <= 255)).all()):
            raise ValueError("calibration: scales must be finite and > 0, zero points within 0..255")

    def check(self, net: EfficientNetLite0) -> Calibration:
        """``self`` when it holds a grid for every activation of ``net`` with the zero point within that
        activation's levels (7 bits where a dense convolution reads it), else ``ValueError``."""
        layers = _layers(net)
        if self.scales.shape != (len(layers) - 1,):
            raise ValueError(f"calibration: expected {len(layers) - 1} activation grids, got {self.scales.shape[0]}")
        for i, (layer, zero) in enumerate(zip(layers, self.zero_points.tolist())):
            if zero > _levels(layers, i):
                raise ValueError(
                    f"calibration: {layer.name}'s zero point {zero} is beyond its {_levels(layers, i)} levels"
                )
        return self


def _grid(lo: float, hi: float, levels: int) -> tuple[float, int]:
    """Scale and zero point of ``levels + 1`` steps covering ``[lo, hi]`` (widened to hold 0 exactly)."""
    lo, hi = min(lo, 0.0), max(hi, 0.0)
    scale = max(hi - lo, 1e-8) / levels
    return scale, min(max(round(-lo / scale), 0), levels)


@dataclass(frozen=True)
class _Bins:
    """A fixed histogram of one activation's values: ``count`` bins of width ``width`` from ``low`` (values beyond
    fall in the end bins). ReLU6 outputs get fine bins on [0, 6], the others coarser ones on [-128, 128]."""

    low: float
    width: float
    count: int

    def index(self, t: Tensor) -> Tensor:
        return ((t - self.low) / self.width).long().clamp_(0, self.count - 1)

    def centres(self) -> Tensor:
        return self.low + self.width * (torch.arange(self.count, dtype=torch.float64) + 0.5)


_RELU6_BINS = _Bins(0.0, 1 / 1024, 6 * 1024)
_SIGNED_BINS = _Bins(-128.0, 1 / 128, 256 * 128)
_STRIDE = 17  # every 17th value of each activation is counted: 17 divides no channel count, so every channel is seen


class Calibrator:
    """The float network of a Lite0 :class:`~classifiers.backbone.Backbone`, run layer by layer, that counts every
    quantized activation's values as it goes; :meth:`calibration` then chooses their 8-bit grids.

    Called like the backbone (normalised ``(B, 3, S, S)`` input, ``(B, 1000)`` float32 scores, the same as the
    backbone's within float rounding), from any number of threads: the statistics (exact range, integer histogram
    counts) do not depend on the order the batches come in, so neither does the calibration.
    """

    def __init__(self, backbone: Backbone):
        _check_lite0(backbone)
        self.name, self.weights_path = backbone.name, backbone.weights_path
        self.input_size, self.mean, self.std = backbone.input_size, backbone.mean, backbone.std
        self.num_features = backbone.num_features
        self._net = backbone.fused_network
        self._layers = _layers(self._net)
        self._lock = threading.Lock()
        self._range: dict[str, tuple[float, float]] = {}
        self._bins = {layer.name: _bins(layer) for layer in self._layers[:-1]}
        self._counts = {name: torch.zeros(bins.count, dtype=torch.int64) for name, bins in self._bins.items()}

    def __call__(
        self, x: Tensor, batch_size: int = 4, threads: int | None = 1, output_device: str | torch.device | None = "cpu"
    ) -> Tensor:
        """Float scores ``(B, 1000)`` of normalised ``x``, in chunks of ``batch_size``, counting the activations."""
        if not isinstance(x, Tensor) or x.ndim != 4 or x.shape[0] == 0:
            raise ValueError(f"x: expected a non-empty (B, 3, S, S) float tensor, got {getattr(x, 'shape', x)}")
        with torch.inference_mode(), torch_threads(threads):
            out = torch.cat(
                [
                    _float_forward(
                        self._net,
                        x[i : i + batch_size].float().contiguous(memory_format=torch.channels_last),
                        self._count,
                    )
                    for i in range(0, x.shape[0], batch_size)
                ]
            )
        return out if output_device is None else out.to(output_device)

    scores = Backbone.scores  # crops -> normalised -> __call__

    def _count(self, name: str, t: Tensor) -> None:
        values = t.permute(0, 2, 3, 1).reshape(-1)[::_STRIDE]  # channels-last memory order
        counts = torch.bincount(self._bins[name].index(values), minlength=self._bins[name].count)
        lo, hi = float(t.min()), float(t.max())
        with self._lock:
            old = self._range.get(name, (lo, hi))
            self._range[name] = (min(old[0], lo), max(old[1], hi))
            self._counts[name] += counts

    def calibration(self) -> Calibration:
        """Each activation's grid: its observed range, shrunk by the fraction of ``_CLIPS`` with the least squared
        quantization error over the counted values (clipping a rare tail buys resolution for the bulk)."""
        if not self._range:
            raise RuntimeError("Calibrator: no images seen yet")
        grids = []
        for i, layer in enumerate(self._layers[:-1]):
            lo, hi = self._range[layer.name]
            counts = self._counts[layer.name]
            grids.append(_least_error_grid(lo, hi, self._bins[layer.name], counts, _levels(self._layers, i)))
        return Calibration(
            torch.tensor([s for s, _ in grids], dtype=torch.float64),
            torch.tensor([z for _, z in grids], dtype=torch.int64),
        )


def _bins(layer: _Layer) -> _Bins:
    return _RELU6_BINS if layer.act == "relu6" else _SIGNED_BINS


def _least_error_grid(lo: float, hi: float, bins: _Bins, counts: Tensor, levels: int) -> tuple[float, int]:
    grids = [_grid(lo * f, hi * f, levels) for f in _CLIPS]
    scale = torch.tensor([g[0] for g in grids], dtype=torch.float64)[:, None]
    zero = torch.tensor([g[1] for g in grids], dtype=torch.float64)[:, None]
    v = bins.centres()[None, :]
    q = torch.clamp(torch.round(v / scale) + zero, 0, levels)
    return grids[int((counts.double() * ((q - zero) * scale - v).pow(2)).sum(1).argmin())]


def calibrate(backbone: Backbone, x: Tensor, batch_size: int = 4) -> Calibration:
    """The 8-bit grids of ``backbone``'s activations measured on normalised images ``x (N, 3, S, S)``
    (:class:`Calibrator` run once over them)."""
    calibrator = Calibrator(backbone)
    calibrator(x, batch_size, threads=None)
    return calibrator.calibration()


# ---- the integer network ----------------------------------------------------------------------------------------
@functools.cache
def _cpu_reason() -> str | None:
    """Why this machine cannot run oneDNN's 8-bit convolutions through torch (``None``: it can)."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return f"oneDNN's 8-bit kernels need an x86-64 CPU, this is {platform.machine()}"
    if not torch.backends.mkldnn.is_available() or not hasattr(torch.ops.onednn, "qconv2d_pointwise"):
        return "this torch build has no oneDNN (mkldnn) 8-bit convolutions"
    if torch.backends.cpu.get_cpu_capability() not in ("AVX2", "AVX512"):
        return f"oneDNN's 8-bit kernels need AVX2 at least, this CPU offers {torch.backends.cpu.get_cpu_capability()}"
    return None


def int8_unavailable(device: torch.device) -> str | None:
    """Why the 8-bit backbone cannot run on ``device`` (``None`` when it can): it is a CPU path on x86-64 with AVX2."""
    if device.type != "cpu":
        return f"8-bit inference runs on the CPU only, the device is {device}"
    return _cpu_reason()


def _check_lite0(backbone: Backbone) -> None:
    if backbone.name != "efficientnet_lite0":
        raise ValueError(f"backbone: 8-bit inference is written for efficientnet_lite0, got {backbone.name!r}")


@dataclass
class _Packed:
    """One integer convolution: oneDNN's packed weights, their scales, float bias, geometry and activation grids."""

    name: str
    weight: Tensor
    weight_scales: Tensor
    bias: Tensor
    stride: int
    padding: int
    groups: int
    act: str
    opens: bool
    x_grid: tuple[float, int]
    out_grid: tuple[float, int] | None  # None: float32 output (the head)
    block_grid: tuple[float, int] | None  # the grid of the block input added to the output ("add" only)
    clip: tuple[float, float]  # the output is clipped to this interval first: ReLU6's, and the grid's levels
    levels: int  # the output's top level


class Int8Backbone:
    """The 8-bit integer twin of a float EfficientNet-Lite0 :class:`~classifiers.backbone.Backbone`.

    Called like the float backbone (normalised ``(B, 3, S, S)`` float input, ``(B, 1000)`` float32 scores) and
    sharing its ``name``, ``weights_path``, ``input_size``, ``mean``, ``std`` and ``num_features``; it runs on the
    CPU only, for the input size it was built for.

    Args:
        backbone: the float backbone whose fused weights are quantized.
        calibration: the activation grids (:func:`calibrate`).
        batch_hint: the batch size the weights are laid out for (oneDNN's AMX kernels otherwise re-lay them out
            on every call for some layers); any batch size runs.
    """

    precision = "int8"
    device = torch.device("cpu")
    dtype = torch.float32

    def __init__(self, backbone: Backbone, calibration: Calibration, batch_hint: int = 4):
        _check_lite0(backbone)
        reason = _cpu_reason()
        if reason is not None:
            raise ValueError(f"precision: {reason}")
        net = backbone.fused_network
        layers = _layers(net)
        calibration.check(net)
        self.name, self.weights_path = backbone.name, backbone.weights_path
        self.input_size, self.mean, self.std = backbone.input_size, backbone.mean, backbone.std
        self.num_features = backbone.num_features
        self.calibration = calibration
        self._fc = net._fc
        grids = list(zip(calibration.scales.tolist(), calibration.zero_points.tolist()))
        x_grid = block_grid = (_INPUT_SCALE, _INPUT_ZERO)
        side = backbone.input_size
        self._plan: list[_Packed] = []
        for i, layer in enumerate(layers):
            block_grid = x_grid if layer.opens else block_grid
            out_grid = grids[i] if i < len(grids) else None
            levels = _levels(layers, i) if out_grid is not None else 0
            clip = (0.0, 6.0) if layer.act == "relu6" else (-math.inf, math.inf)
            if out_grid is not None:  # no value beyond the grid's levels: 7-bit outputs stay below 128
                clip = (max(clip[0], -out_grid[1] * out_grid[0]), min(clip[1], (levels - out_grid[1]) * out_grid[0]))
            shape = [batch_hint, layer.conv.in_channels, side, side]
            block = block_grid if layer.act == "add" else None
            self._plan.append(_pack(layer, x_grid, out_grid, block, clip, levels, shape))
            side = -(-side // layer.conv.stride[0])
            x_grid = out_grid

    def __call__(
        self, x: Tensor, batch_size: int = 4, threads: int | None = 1, output_device: str | torch.device | None = "cpu"
    ) -> Tensor:
        """ImageNet scores ``(B, 1000)`` float32 of normalised input ``(B, 3, S, S)`` (``S = input_size``), in chunks
        of ``batch_size`` on ``threads`` intra-op threads (``None``: torch's setting), returned on ``output_device``."""
        if not isinstance(x, Tensor) or x.ndim != 4 or tuple(x.shape[1:]) != (3, self.input_size, self.input_size):
            raise ValueError(
                f"x: expected a (B, 3, {self.input_size}, {self.input_size}) float tensor, "
                f"got {getattr(x, 'shape', type(x))}"
            )
        if batch_size < 1:
            raise ValueError(f"batch_size: expected >= 1, got {batch_size}")
        with torch.inference_mode(), torch_threads(threads):
            outs = [self._forward(x[i : i + batch_size]) for i in range(0, x.shape[0], batch_size)]
            out = torch.cat(outs) if outs else torch.zeros(0, self.num_features)
        return out if output_device is None else out.to(output_device)

    def scores(self, crops: np.ndarray | Sequence[np.ndarray], batch_size: int = 4, threads: int | None = 1) -> Tensor:
        """Scores ``(B, 1000)`` of uint8 BGR crops ``(B, S, S, 3)``, the same as ``self(normalize(crops))``: the
        pixels go onto the stem's grid in one compiled pass, with no float image in between."""
        arr = np.ascontiguousarray(crops if isinstance(crops, np.ndarray) else np.stack(list(crops)))
        if arr.dtype != np.uint8 or arr.ndim != 4 or arr.shape[1:] != (self.input_size, self.input_size, 3):
            raise ValueError(f"crops: expected uint8 (B, {self.input_size}, {self.input_size}, 3), got {arr.shape}")
        mean, inv = np.asarray(self.mean, np.float32), 1.0 / np.asarray(self.std, np.float32)
        q = torch.from_numpy(_pixels_on_grid(arr, mean, inv)).permute(0, 3, 1, 2)  # channels-last (B, 3, S, S)
        with torch.inference_mode(), torch_threads(threads):
            return torch.cat([self._run_plan(q[i : i + batch_size]) for i in range(0, q.shape[0], batch_size)])

    def _forward(self, x: Tensor) -> Tensor:
        return self._run_plan(_quantize_input(x.to("cpu", torch.float32)))

    def _run_plan(self, q: Tensor) -> Tensor:
        """Scores of the stem's uint8 input ``q`` (mirrored, channels-last)."""
        block_in = q
        for layer in self._plan:
            if layer.opens:
                block_in = q
            q = _run(layer, q, block_in)
        return F.linear(q.mean(dim=(2, 3)), self._fc.weight, self._fc.bias)


def _quantize_input(x: Tensor) -> Tensor:
    """Normalised float input ``(B, 3, S, S)`` -> the stem's 7-bit grid, mirrored in both axes, channels-last uint8."""
    q = torch.round(x.flip(2, 3) / _INPUT_SCALE).add_(_INPUT_ZERO).clamp_(0, _DENSE_LEVELS)
    return q.to(torch.uint8).contiguous(memory_format=torch.channels_last)


@njit(cache=True)
def _pixels_on_grid(arr: np.ndarray, mean: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """uint8 BGR ``(B, S, S, 3)`` -> :func:`_quantize_input` of its normalised RGB, as ``(B, S, S, 3)`` uint8: the
    float32 value of :func:`~classifiers.preprocess.normalize`, mirrored, divided by the (power of two) input step,
    rounded half to even, shifted and clipped, exactly as there."""
    b, h, w, _ = arr.shape
    out = np.empty(arr.shape, np.uint8)
    step = np.float32(_INPUT_SCALE)
    for i in range(b):
        for y in range(h):
            for x in range(w):
                for k in range(3):
                    v = (np.float32(arr[i, h - 1 - y, w - 1 - x, 2 - k]) - mean[k]) * inv[k]
                    q = np.rint(v / step) + np.float32(_INPUT_ZERO)
                    out[i, y, x, k] = np.uint8(min(max(q, np.float32(0)), np.float32(_DENSE_LEVELS)))
    return out


def _pack(
    layer: _Layer,
    x_grid: tuple[float, int],
    out_grid: tuple[float, int] | None,
    block_grid: tuple[float, int] | None,
    clip: tuple[float, float],
    levels: int,
    x_shape: list[int],
) -> _Packed:
    """Quantize and lay out one convolution (kernel mirrored in both axes, symmetric ``k // 2`` padding)."""
    conv = layer.conv
    k, s = conv.kernel_size[0], conv.stride[0]
    if conv.kernel_size[0] != conv.kernel_size[1] or k % 2 == 0 or conv.stride[0] != conv.stride[1]:
        raise ValueError(f"{layer.name}: the mirrored plan needs square odd kernels and equal strides")
    if s > 1 and x_shape[2] % 2:
        raise ValueError(f"{layer.name}: the mirrored plan needs an even input side under a stride, got {x_shape[2]}")
    w = conv.weight.detach().float().flip(2, 3)
    scales = (w.abs().amax(dim=(1, 2, 3)) / _WEIGHT_LEVELS).clamp_min(1e-12)
    qw = torch.round(w / scales[:, None, None, None]).clamp_(-_WEIGHT_LEVELS, _WEIGHT_LEVELS).to(torch.int8)
    packed = torch.ops.onednn.qconv_prepack(
        qw, scales, x_grid[0], x_grid[1], [s, s], [k // 2, k // 2], [1, 1], conv.groups, x_shape
    )
    bias = conv.bias.detach().float() if conv.bias is not None else torch.zeros(conv.out_channels)
    return _Packed(
        layer.name, packed, scales, bias, s, k // 2, conv.groups, layer.act, layer.opens,
        x_grid, out_grid, block_grid, clip, levels,
    )  # fmt: skip


_NO_ZERO = torch.zeros(1, dtype=torch.int32)  # the weights' zero point (symmetric)


def _run(layer: _Packed, q: Tensor, block_in: Tensor) -> Tensor:
    """One integer convolution of ``q`` (uint8 on ``layer.x_grid``) with its activation, onto ``layer.out_grid``."""
    geometry = ([layer.stride] * 2, [layer.padding] * 2, [1, 1], layer.groups)
    head = (layer.weight, layer.weight_scales, _NO_ZERO)
    clip = list(layer.clip)
    if layer.act == "add":  # the residual sum is fused: written into the block input's buffer (read by no one else)
        out = torch.ops.onednn.qconv2d_pointwise.binary(
            q, *layer.x_grid, *head, block_in, layer.bias, *geometry, *layer.out_grid, None,
            *layer.block_grid, "sum", 1.0, "none", [], "",
        )  # fmt: skip
        return out.clamp_(max=layer.levels)  # oneDNN takes no clip after a sum: saturate at the grid's top here
    out_scale, out_zero, out_dtype = (1.0, 0, torch.float32) if layer.out_grid is None else (*layer.out_grid, None)
    return torch.ops.onednn.qconv2d_pointwise(
        q, *layer.x_grid, *head, layer.bias, *geometry, out_scale, out_zero, out_dtype, "hardtanh", clip, ""
    )
