"""The 8-bit backbone: the integer arithmetic it means, against the float32 oracle on real frames, determinism,
storage, settings and refusals.

Tolerances: every activation is rounded to a grid of 128 or 256 steps over its range, a relative error of a few
percent per layer (a step over sqrt(12), against activations whose RMS is a tenth of their range); over the 49
convolutions these add up to about 12 % of the score vector's norm on mission frames (measured 0.10-0.13 on rendered
mission frames), and most frames keep their top ImageNet class. The bounds below sit well outside that spread and
far inside what a broken layer gives (a saturating AVX2 kernel: 0.34; a mis-padded convolution: > 0.5).
"""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import classifiers.quantize as quantize
from classifiers import FrameClassifier, center_crop, normalize
from classifiers.data import render_images, render_sequence
from classifiers.quantize import Calibration, Int8Backbone, point_names
from hbni_infra.tensorfile import load_tensors, save_tensors

VEHICLES = ("irobot", "quadrotor", "racecar")

pytestmark = pytest.mark.skipif(
    quantize.int8_unavailable(torch.device("cpu")) is not None,
    reason=f"no 8-bit kernels here: {quantize.int8_unavailable(torch.device('cpu'))}",
)


@pytest.fixture(scope="module")
def training():
    images = np.concatenate([render_images(name, 4, "training", seed=11) for name in VEHICLES])
    return images, np.repeat(VEHICLES, 4)


@pytest.fixture(scope="module")
def int8_classifier(training):
    return FrameClassifier(cv=2, seed=1).fit(*training, augment=1)


@pytest.fixture(scope="module")
def mission(int8_classifier):
    """Normalised centre crops ``(12, 3, 224, 224)`` of mission-condition frames, four per vehicle."""
    frames = np.concatenate([render_sequence(name, 4, "mission", seed=12) for name in VEHICLES])
    backbone = int8_classifier.backbone_
    x = normalize([center_crop(im, backbone.input_size, 0.1) for im in frames], backbone.mean, backbone.std)
    return frames, x


def _layer_outputs(net: Int8Backbone, x: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Each integer convolution's input and output (uint8, or float32 for the head) on ``x``."""
    out = []
    with torch.inference_mode():
        q = block_in = quantize._quantize_input(x)
        for layer in net._plan:
            if layer.opens:
                block_in = q
            skip = block_in.clone() if layer.act == "add" else None  # the sum is written into the block input
            y = quantize._run(layer, q, block_in)
            out.append((q.clone(), skip, y.clone()))
            q = y
    return out


def _exact(layer: quantize._Packed, weight: torch.Tensor, q: torch.Tensor, skip: torch.Tensor | None) -> torch.Tensor:
    """What ``layer`` means, on integers summed exactly (in float32 while no sum can pass 2**24, else float64): conv,
    rescale, bias, ReLU6 or sum, round to the grid."""
    (xs, xz), k = layer.x_grid, layer.padding
    exact = torch.float32 if weight[0].numel() * 255 * 127 < 2**24 else torch.float64
    acc = F.conv2d(q.to(exact) - xz, weight.to(exact), None, layer.stride, k, 1, layer.groups).double()
    y = acc * xs * layer.weight_scales.double()[None, :, None, None] + layer.bias.double()[None, :, None, None]
    if layer.act == "relu6":
        y = y.clamp(0, 6)
    if layer.act == "add":
        y = y + (skip.double() - layer.block_grid[1]) * layer.block_grid[0]
    if layer.out_grid is None:
        return y
    scale, zero = layer.out_grid
    levels = 255 if layer.name.endswith(".expand") or layer.name == "stem" else 127
    return (torch.round(y / scale) + zero).clamp(0, levels)


def test_kernels_compute_the_exact_integer_arithmetic(int8_classifier, mission):
    """Every layer's output, from the layer's own input, is the exact integer computation rounded to its grid: equal,
    or one step off where float rounding of the rescale lands on a half (no saturation, padding or layout error)."""
    net = int8_classifier._network()
    convs = [layer.conv for layer in quantize._layers(int8_classifier.backbone_.fused_network)]
    for layer, conv, (q, skip, y) in zip(net._plan, convs, _layer_outputs(net, mission[1][:1])):
        w = conv.weight.detach().float().flip(2, 3)
        weight = torch.round(w / layer.weight_scales[:, None, None, None]).clamp(-127, 127)
        ref = _exact(layer, weight, q, skip)
        if layer.out_grid is None:
            torch.testing.assert_close(y.double(), ref, rtol=1e-5, atol=1e-4)
            continue
        steps = (y.double() - ref).abs()
        assert steps.max() <= 1 + 6 * (layer.act == "add"), layer.name  # the sum rounds its operands once more
        assert float((steps > 0).double().mean()) < 0.01, layer.name


def test_dense_inputs_are_seven_bit_and_cannot_saturate_avx2(int8_classifier):
    """AVX2 adds pairs of uint8 x int8 products in 16 bits: a dense convolution's inputs stay <= 127."""
    net = int8_classifier._network()
    for layer in net._plan:
        scale, zero = layer.x_grid
        if layer.groups == 1:
            assert zero <= 127 and 2 * 127 * 127 < 2**15
    for name, zero in zip(point_names(int8_classifier.backbone_.fused_network), net.calibration.zero_points):
        assert 0 <= zero <= (255 if name.endswith(".expand") or name == "stem" else 127)


def test_mirrored_plan_is_tensorflows_same_padding(int8_classifier):
    """Mirrored input, mirrored kernel, symmetric k // 2 padding = the SAME convolution, mirrored."""
    g = torch.Generator().manual_seed(0)
    for layer in quantize._layers(int8_classifier.backbone_.fused_network):
        conv = layer.conv
        x = torch.randn(1, conv.in_channels, 14, 14, generator=g)
        k, s = conv.kernel_size[0], conv.stride[0]
        with torch.inference_mode():
            same = conv(x).flip(2, 3)
            mirrored = F.conv2d(x.flip(2, 3), conv.weight.flip(2, 3), conv.bias, s, k // 2, 1, conv.groups)
        torch.testing.assert_close(mirrored, same, rtol=1e-4, atol=1e-4)


def test_int8_scores_follow_the_float32_oracle_on_mission_frames(int8_classifier, mission):
    frames, x = mission
    f = int8_classifier.backbone_(x)
    q = int8_classifier._network()(x)
    assert q.shape == f.shape == (12, 1000) and q.dtype == torch.float32
    relative = float((q - f).norm() / f.norm())
    correlation = min(float(np.corrcoef(a, b)[0, 1]) for a, b in zip(q.numpy(), f.numpy()))
    top1 = float((q.argmax(-1) == f.argmax(-1)).double().mean())
    print(f"relative error {relative:.3f}, least per-frame correlation {correlation:.3f}, top-1 agreement {top1:.2f}")
    assert relative < 0.2 and correlation > 0.95 and top1 >= 0.75
    # the classifier's head sees the 8-bit scores: its labels agree with the float oracle's on most frames
    float_twin = FrameClassifier(**(int8_classifier.get_params() | {"precision": "float"}))
    float_twin.head_, float_twin.mean_, float_twin.scale_ = (
        int8_classifier.head_,
        int8_classifier.mean_,
        int8_classifier.scale_,
    )
    agree = (int8_classifier.proba(frames).argmax(-1) == float_twin.proba(frames).argmax(-1)).double().mean()
    assert float(agree) >= 0.75


def test_deterministic_across_calls_threads_and_batches(int8_classifier, mission):
    net, x = int8_classifier._network(), mission[1]
    once = net(x, batch_size=4, threads=1)
    assert torch.equal(net(x, batch_size=4, threads=1), once)
    assert torch.equal(net(x, batch_size=4, threads=2), once)  # integer sums: any split of the work
    torch.testing.assert_close(net(x, batch_size=1), once, rtol=0, atol=1e-4)  # only the float pool/linear layer
    frames = mission[0]
    assert torch.equal(int8_classifier.proba(frames), int8_classifier.proba(frames))


def test_save_load_round_trip_is_bit_exact(tmp_path, int8_classifier, mission):
    path = int8_classifier.save(tmp_path / "clf.safetensors")
    tensors, meta = load_tensors(path, "classifiers.FrameClassifier")
    assert meta["precision"] == "int8" and tensors["calibration.scales"].dtype == torch.float64
    loaded = FrameClassifier.load(path)
    assert loaded.precision == "int8" and loaded.precision_ == "int8"
    assert torch.equal(loaded.proba(mission[0]), int8_classifier.proba(mission[0]))
    assert torch.equal(loaded._network()(mission[1]), int8_classifier._network()(mission[1]))


def test_copies_rebuild_the_packed_network(int8_classifier, mission):
    """oneDNN's packed weights cannot be copied: pickle and deepcopy leave them out, and the copy rebuilds them."""
    import copy
    import pickle

    expected = int8_classifier.proba(mission[0])
    for twin in (pickle.loads(pickle.dumps(int8_classifier)), copy.deepcopy(int8_classifier)):
        assert "_int8_backbone" not in twin.__dict__ and torch.equal(twin.proba(mission[0]), expected)


def test_a_file_from_before_8_bit_loads_as_float(tmp_path, int8_classifier, mission):
    float_clf = FrameClassifier(**(int8_classifier.get_params() | {"precision": "float"}))
    float_clf.head_, float_clf.mean_, float_clf.scale_ = (
        int8_classifier.head_,
        int8_classifier.mean_,
        int8_classifier.scale_,
    )
    tensors, meta = load_tensors(float_clf.save(tmp_path / "new.safetensors"), "classifiers.FrameClassifier")
    del meta["precision"]  # what a file written before the 8-bit path holds
    old = save_tensors(tmp_path / "old.safetensors", "classifiers.FrameClassifier", tensors, meta)
    loaded = FrameClassifier.load(old)
    assert loaded.precision == "float" and loaded.precision_ == "float"
    assert torch.equal(loaded.proba(mission[0]), float_clf.proba(mission[0]))


def test_a_damaged_calibration_is_refused(tmp_path, int8_classifier):
    tensors, meta = load_tensors(int8_classifier.save(tmp_path / "a.safetensors"), "classifiers.FrameClassifier")
    short = tensors | {"calibration.scales": tensors["calibration.scales"][:-1]}
    with pytest.raises(ValueError, match="calibration"):
        FrameClassifier.load(save_tensors(tmp_path / "b.safetensors", "classifiers.FrameClassifier", short, meta))
    negative = tensors | {"calibration.scales": -tensors["calibration.scales"]}
    with pytest.raises(ValueError, match="calibration.*scales must be finite and > 0"):
        FrameClassifier.load(save_tensors(tmp_path / "c.safetensors", "classifiers.FrameClassifier", negative, meta))
    missing = {k: v for k, v in tensors.items() if k != "calibration.zero_points"}
    with pytest.raises(ValueError, match="calibration: missing 'calibration.zero_points'"):
        FrameClassifier.load(save_tensors(tmp_path / "d.safetensors", "classifiers.FrameClassifier", missing, meta))
    eight_bit = tensors | {"calibration.zero_points": torch.full_like(tensors["calibration.zero_points"], 200)}
    with pytest.raises(
        ValueError, match="0.depthwise's zero point 200 is beyond its 127 levels"
    ):  # AVX2 would overflow
        FrameClassifier.load(save_tensors(tmp_path / "e.safetensors", "classifiers.FrameClassifier", eight_bit, meta))


def test_precision_settings(int8_classifier):
    from sklearn.base import clone

    assert FrameClassifier().precision == "auto" and FrameClassifier().precision_ == "int8"
    assert FrameClassifier(device="meta").precision_ == "float"  # auto: float off the CPU
    clf = FrameClassifier(precision="float", C=2.0)
    assert clf.get_params()["precision"] == "float" and clone(clf).precision == "float"
    assert repr(clf) == "FrameClassifier(C=2.0, precision='float')"
    assert clf.set_params(precision="int8").precision_ == "int8"
    copy = clone(int8_classifier)
    assert copy.get_params() == int8_classifier.get_params() and "calibration_" not in copy.__dict__
    with pytest.raises(RuntimeError, match="not calibrated.*fit"):
        copy.features(np.zeros((1, 32, 32, 3), np.uint8))
    with pytest.raises(ValueError, match="precision: calibration is for the 8-bit backbone"):
        FrameClassifier(precision="float").calibrate(np.zeros((1, 32, 32, 3), np.uint8))


@pytest.mark.parametrize(
    ("params", "error", "message"),
    [
        ({"precision": "int4"}, ValueError, r"precision: expected one of \['auto', 'int8', 'float'\]"),
        ({"precision": 8}, TypeError, "precision: expected one of"),
        (
            {"precision": "int8", "device": "meta"},
            ValueError,
            "precision: 'int8' cannot run here: 8-bit inference runs on the CPU only",
        ),  # fmt: skip
        ({"precision": "int8", "device": "meta", "dtype": torch.float16}, ValueError, "replaces float32"),
    ],
)
def test_bad_precisions_are_refused(params, error, message):
    with pytest.raises(error, match=message):
        FrameClassifier(**params)
    clf = FrameClassifier(precision="float")
    with pytest.raises(error, match=message):
        clf.set_params(**params)
    assert clf.precision == "float" and clf.device == "cpu"


def test_a_cpu_without_the_kernels(monkeypatch, tmp_path, int8_classifier):
    """Where oneDNN's 8-bit kernels are missing (an ARM robot), "auto" runs float, "int8" and 8-bit files are refused."""
    path = int8_classifier.save(tmp_path / "clf.safetensors")
    monkeypatch.setattr(quantize.platform, "machine", lambda: "aarch64")
    quantize._cpu_reason.cache_clear()
    try:
        assert FrameClassifier().precision_ == "float"
        with pytest.raises(ValueError, match="precision: 'int8' cannot run here: .*x86-64 CPU, this is aarch64"):
            FrameClassifier(precision="int8")
        with pytest.raises(ValueError, match="holds an invalid setting: precision: 'int8' cannot run here"):
            FrameClassifier.load(path)
    finally:
        monkeypatch.undo()
        quantize._cpu_reason.cache_clear()


def test_backbone_input_and_calibration_errors(int8_classifier):
    net = int8_classifier._network()
    with pytest.raises(ValueError, match=r"x: expected a \(B, 3, 224, 224\)"):
        net(torch.zeros(1, 3, 112, 112))
    with pytest.raises(ValueError, match="batch_size"):
        net(torch.zeros(1, 3, 224, 224), batch_size=0)
    with pytest.raises(ValueError, match="calibration: expected 48 activation grids"):
        Int8Backbone(int8_classifier.backbone_, Calibration(torch.ones(3, dtype=torch.float64), torch.zeros(3).long()))
    with pytest.raises(ValueError, match="float64 scales and int64 zero points"):
        Calibration(torch.ones(3), torch.zeros(3).long())
    with pytest.raises(ValueError, match="zero points within 0..255"):
        Calibration(torch.ones(3, dtype=torch.float64), torch.full((3,), 256))
    with pytest.raises(RuntimeError, match="no images seen"):
        quantize.Calibrator(int8_classifier.backbone_).calibration()


@pytest.mark.skipif(
    torch.backends.cpu.get_cpu_capability() != "AVX512", reason="only a CPU beyond AVX2 can stand in for one"
)
def test_avx2_kernels_give_the_same_scores(int8_classifier, mission, tmp_path):
    """oneDNN capped at AVX2 (``ONEDNN_MAX_CPU_ISA``, read when it starts) classifies like this CPU's kernels: no
    16-bit saturation (8-bit dense inputs there gave a relative error of 0.34 against float32)."""
    path = int8_classifier.save(tmp_path / "clf.safetensors")
    torch.save(mission[1][:4].clone(), tmp_path / "x.pt")
    script = (
        "import sys, torch; from classifiers import FrameClassifier\n"
        "clf = FrameClassifier.load(sys.argv[1]); x = torch.load(sys.argv[2])\n"
        "torch.save(clf._network()(x), sys.argv[3])\n"
    )
    env = os.environ | {"ONEDNN_MAX_CPU_ISA": "AVX2", "ONEDNN_VERBOSE": "0"}
    args = [sys.executable, "-c", script, str(path), str(tmp_path / "x.pt"), str(tmp_path / "out.pt")]
    subprocess.run(args, env=env, check=True, timeout=300)
    avx2 = torch.load(tmp_path / "out.pt")
    here = int8_classifier._network()(mission[1][:4])
    float_scores = int8_classifier.backbone_(mission[1][:4])
    between = float((avx2 - here).norm() / here.norm())
    print(f"AVX2 against this CPU's kernels: relative difference {between:.4f}")
    assert between < 0.05
    assert float((avx2 - float_scores).norm() / float_scores.norm()) < 0.2
