"""The EfficientNet-Lite0 backbone: real ImageNet weights loaded offline, TensorFlow padding, fused == unfused, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from classifiers import Backbone, FrameClassifier, center_crop, default_weights_path, normalize
from classifiers.backbone import EfficientNetLite0, SameConv2d, fuse_batchnorm

skimage_data = pytest.importorskip("skimage.data")

CAT = set(range(281, 286))  # tabby, tiger cat, Persian, Siamese, Egyptian cat
COFFEE = {504, 967, 968}  # coffee mug, espresso, cup


def _scores(backbone, rgb: np.ndarray) -> torch.Tensor:
    crop = center_crop(np.ascontiguousarray(rgb[..., ::-1]), backbone.input_size)
    return torch.softmax(backbone(normalize(crop[None], backbone.mean, backbone.std)), -1)[0]


@pytest.mark.parametrize(("photo", "group"), [("chelsea", CAT), ("coffee", COFFEE)])
def test_classifies_bundled_photos(backbone, photo, group):
    p = _scores(backbone, getattr(skimage_data, photo)())
    top = int(p.argmax())
    assert top in group, f"{photo}: top-1 class {top}"
    assert float(p[list(group)].sum()) > 0.5


def test_state_dict_keys_match_strictly():
    state = torch.load(default_weights_path(), map_location="cpu", weights_only=True)
    net = EfficientNetLite0()
    assert set(net.state_dict()) == set(state)
    net.load_state_dict(state, strict=True)


def test_fused_matches_unfused_and_batching(backbone):
    x = torch.randn(5, 3, 224, 224, generator=torch.Generator().manual_seed(0))
    with torch.inference_mode():
        ref = backbone.net(x)
    fused = fuse_batchnorm(backbone.net)
    with torch.inference_mode():
        assert torch.allclose(fused(x), ref, atol=1e-3, rtol=1e-4)
    assert not backbone.net.training
    out = backbone(x, batch_size=2)
    assert out.shape == (5, 1000)
    assert torch.allclose(out, ref, atol=1e-3, rtol=1e-4)
    assert torch.allclose(backbone(x[:1]), out[:1], atol=1e-4)  # batch composition does not matter


@pytest.mark.parametrize("size", [(224, 224), (7, 9), (14, 13)])
@pytest.mark.parametrize(("kernel", "stride"), [(1, 1), (2, 1), (3, 1), (5, 1), (1, 2), (3, 2), (5, 2), (3, 3)])
@pytest.mark.parametrize(("groups", "bias"), [(4, False), (1, True)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_same_padding_is_tensorflows(size, kernel, stride, groups, bias, channels_last):
    """TensorFlow's "SAME": output ceil(size / stride), the pad split with the odd pixel at the bottom/right; the
    convolution on an explicitly padded copy is the reference of every path (1x1 product, even padding and crop,
    explicit padding for an even kernel)."""
    g = torch.Generator().manual_seed(0)
    conv = SameConv2d(4, 4, kernel, stride=stride, groups=groups, bias=bias)
    x = torch.randn(2, 4, *size, generator=g)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    pads = []
    for n in size[::-1]:
        total = max((-(-n // stride) - 1) * stride + kernel - n, 0)
        pads += [total // 2, total - total // 2]
    ref = torch.nn.functional.conv2d(torch.nn.functional.pad(x, pads), conv.weight, conv.bias, stride, 0, 1, groups)
    with torch.inference_mode():
        out = conv(x)
    assert out.shape == (2, 4, -(-size[0] // stride), -(-size[1] // stride))
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6)


def test_missing_weights_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="weights_path"):
        Backbone(weights_path=tmp_path / "nope.pth")
    with pytest.raises(FileNotFoundError, match="weights_path"):
        FrameClassifier(weights_path=tmp_path / "nope.pth")


def test_corrupt_or_foreign_weights(tmp_path):
    bad = tmp_path / "bad.pth"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="weights_path"):
        Backbone(weights_path=bad)
    foreign = tmp_path / "foreign.pth"
    torch.save({"layer.weight": torch.zeros(2, 2)}, foreign)
    with pytest.raises(ValueError, match="does not match"):
        Backbone(weights_path=foreign)


def test_bad_arguments(backbone):
    with pytest.raises(ValueError, match="name"):
        Backbone(name="resnet")
    with pytest.raises(ValueError, match="weights_path"):
        Backbone(name="alexnet")
    with pytest.raises(ValueError, match="x"):
        backbone(torch.zeros(1, 4, 224, 224))
