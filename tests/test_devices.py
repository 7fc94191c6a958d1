"""Device handling of the CNN backbone, the frame classifier, exact controller evaluation and the torch simulator.

On the CPU every device-aware call must return its tensors on the requested device and equal the default path
exactly; ``"meta"`` tensors check shapes where no values are needed. CUDA variants run only where CUDA is present.
"""

import math

import numpy as np
import pytest
import torch

from classifiers import FrameClassifier, load_backbone
from classifiers.backbone import HALF_TOLERANCE, Backbone
from decpomdp import random_controllers, simulate
from decpomdp.domains.disaster_relief import DisasterRelief
from decpomdp.domains.package_delivery import PackageDelivery
from decpomdp.dpomdp import TabularDecPOSMDP, exact_value
from decpomdp.dpomdp.backup import operator_for

cuda = pytest.mark.cuda
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


def _inputs(batch: int = 3, seed: int = 0) -> torch.Tensor:
    return torch.randn(batch, 3, 224, 224, generator=torch.Generator().manual_seed(seed))


def _images(count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(count, 60, 80, 3), dtype=np.uint8)


@pytest.fixture(scope="module")
def tiger():
    return TabularDecPOSMDP.from_problem("dectiger", gamma=0.9, horizon=4)


@pytest.fixture(scope="module")
def controllers():
    return random_controllers(
        6, num_agents=2, num_nodes=3, num_actions=3, num_obs=2, generator=torch.Generator().manual_seed(3)
    )


# ---- backbone -----------------------------------------------------------------------------------------------
def test_backbone_cpu_device_equals_default():
    x = _inputs()
    default = load_backbone()
    explicit = Backbone(device="cpu")
    assert default.device == torch.device("cpu") and default.dtype == torch.float32
    assert torch.equal(explicit(x, batch_size=2), default(x, batch_size=2))
    assert load_backbone(device="cpu") is default and default.to("cpu") is default


def test_backbone_meta_shapes_and_output_device():
    meta = load_backbone().to("meta")
    assert meta.device == torch.device("meta") and load_backbone().device == torch.device("cpu")
    out = meta(_inputs(5), batch_size=2, output_device=None)
    assert out.device == torch.device("meta") and out.shape == (5, 1000) and out.dtype == torch.float32
    half = load_backbone(device="meta", dtype=torch.float16)
    out = half(_inputs(2), output_device=None)
    assert out.shape == (2, 1000) and out.dtype == torch.float32  # scores come back in float32


def test_backbone_device_arguments_are_checked():
    with pytest.raises(ValueError, match="dtype"):
        Backbone(device="cpu", half=True)
    with pytest.raises(ValueError, match="dtype"):
        load_backbone().to("cpu", torch.float64)
    with pytest.raises(ValueError, match="device"):
        load_backbone().to("no-such-device")
    with pytest.raises(ValueError, match="half"):
        Backbone(device="meta", dtype=torch.bfloat16, half=True)


# ---- frame classifier ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fitted():
    """A float classifier: the path that runs on every device (the 8-bit one is a CPU path, refused elsewhere)."""
    images, labels = _images(12, 1), ["a", "b", "c"] * 4
    return FrameClassifier(cv=2, precision="float").fit(images, labels)


def test_classifier_cpu_device_equals_default(fitted, tmp_path):
    images = _images(4, 2)
    expected = fitted.proba(images)
    assert fitted.backbone_.device == torch.device("cpu") and expected.device == torch.device("cpu")
    path = fitted.save(tmp_path / "clf.safetensors")
    loaded = FrameClassifier.load(path, device="cpu")
    assert loaded.backbone_.device == torch.device("cpu")
    assert torch.equal(loaded.proba(images), expected)
    assert torch.equal(loaded.to("cpu").features(images), fitted.features(images))


def test_an_8_bit_classifier_stays_on_the_cpu(tmp_path):
    images, labels = _images(12, 1), ["a", "b", "c"] * 4
    clf = FrameClassifier(cv=2, precision="int8").fit(images, labels)
    with pytest.raises(ValueError, match="holds an invalid setting: precision: 'int8' cannot run here: 8-bit inference "
                       "runs on the CPU only, the device is meta"):  # fmt: skip
        FrameClassifier.load(clf.save(tmp_path / "clf.safetensors"), device="meta")
    with pytest.raises(ValueError, match="precision: 'int8' cannot run here"):
        clf.to("meta")
    assert clf.device == "cpu" and clf.precision_ == "int8"


def test_classifier_to_meta_moves_only_the_backbone(fitted, tmp_path):
    loaded = FrameClassifier.load(fitted.save(tmp_path / "clf.safetensors"), device="meta")
    assert loaded.backbone_.device == torch.device("meta") and loaded.mean_.device == torch.device("cpu")
    assert loaded.to("cpu") is loaded and loaded.backbone_.device == torch.device("cpu")
    assert fitted.backbone_.device == torch.device("cpu")  # the shared backbone was not moved


# ---- exact evaluation ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("horizon", [4, math.inf])
def test_exact_cpu_device_is_bit_identical(tiger, controllers, horizon):
    default = exact_value(tiger, controllers, horizon=horizon)
    explicit = exact_value(tiger, controllers, horizon=horizon, device="cpu")
    assert explicit.device == torch.device("cpu") and explicit.dtype == torch.float64
    assert torch.equal(explicit, default)


def test_exact_gmres_cpu_device_within_its_tolerance(tiger, controllers):
    # two identical default calls on the GMRES path already differ in the last bits (the dense and finite-horizon
    # paths do not): each result lies within tol of the exact value, hence within 2 * tol of the other
    tol = 1e-10
    default = exact_value(tiger, controllers, horizon=math.inf, max_dense=1, tol=tol)
    explicit = exact_value(tiger, controllers, horizon=math.inf, max_dense=1, tol=tol, device="cpu")
    assert explicit.device == torch.device("cpu")
    assert (explicit - default).abs().max() <= 2 * tol


def test_operator_is_cached_per_device(tiger):
    op = operator_for(tiger, "cpu")
    assert op is operator_for(tiger) and op.device == torch.device("cpu")
    assert op.reward.device == op.obs_rows.device == torch.device("cpu")


# ---- torch simulator ----------------------------------------------------------------------------------------
def test_torch_simulator_on_cpu_generator_device(tiger, controllers):
    returns = simulate(tiger, controllers, 50, torch.Generator(device="cpu").manual_seed(1), backend="torch")
    assert returns.device == torch.device("cpu") and returns.shape == (6, 50) and returns.dtype == torch.float64
    assert torch.equal(returns, simulate(tiger, controllers, 50, torch.Generator().manual_seed(1), backend="torch"))


def _domain_controllers(env, count: int = 3):
    return random_controllers(
        count,
        num_agents=env.num_agents,
        num_nodes=3,
        num_actions=env.num_actions,
        num_obs=env.num_obs,
        generator=torch.Generator().manual_seed(5),
    )


@pytest.mark.parametrize(
    "env",
    [DisasterRelief(), PackageDelivery(), PackageDelivery(successor_rule=True)],
    ids=["disaster_relief", "package_delivery", "package_delivery_successors"],
)
def test_domain_oracles_on_cpu_generator_device(env):
    ctrl = _domain_controllers(env)
    returns = simulate(env, ctrl, 20, torch.Generator(device="cpu").manual_seed(1), backend="torch")
    assert returns.device == torch.device("cpu") and returns.shape == (3, 20)
    assert torch.equal(returns, simulate(env, ctrl, 20, torch.Generator().manual_seed(1), backend="torch"))


def test_tabular_index_helpers_keep_the_device(tiger):
    jo = torch.arange(4, device="meta")
    assert tiger.split_obs(jo).device == torch.device("meta") and tiger.split_obs(jo).shape == (4, 2)
    assert tiger.joint_action(torch.zeros(3, 2, dtype=torch.long, device="meta")).shape == (3,)


# ---- CUDA ---------------------------------------------------------------------------------------------------
@cuda
@needs_cuda
def test_backbone_cuda_matches_cpu_and_half_within_tolerance():
    x = _inputs(8)
    cpu = load_backbone()(x)
    gpu = load_backbone(device="cuda")(x, batch_size=8)
    assert gpu.device == torch.device("cpu")
    assert torch.allclose(gpu, cpu, atol=1e-3, rtol=1e-3)
    on_device = load_backbone(device="cuda")(x, output_device=None)
    assert on_device.device.type == "cuda"
    half = load_backbone(device="cuda", dtype=torch.float16)(x, batch_size=8)
    assert (torch.softmax(half, -1) - torch.softmax(cpu, -1)).abs().max() <= HALF_TOLERANCE


@cuda
@needs_cuda
def test_classifier_loads_on_cuda(fitted, tmp_path):
    images = _images(4, 2)
    loaded = FrameClassifier.load(fitted.save(tmp_path / "clf.safetensors"), device="cuda")
    proba = loaded.proba(images)
    assert proba.device == torch.device("cpu")
    assert torch.allclose(proba, fitted.proba(images), atol=1e-4)


@cuda
@needs_cuda
@pytest.mark.parametrize("max_dense", [300, 1])
@pytest.mark.parametrize("horizon", [4, math.inf])
def test_exact_cuda_matches_cpu(tiger, controllers, horizon, max_dense):
    cpu = exact_value(tiger, controllers, horizon=horizon, max_dense=max_dense)
    gpu = exact_value(tiger, controllers, horizon=horizon, max_dense=max_dense, device="cuda")
    assert gpu.device.type == "cuda"
    on_input = exact_value(
        tiger,
        type(controllers)(controllers.action.cuda(), controllers.next_node.cuda()),
        horizon=horizon,
        max_dense=max_dense,
    )
    assert on_input.device.type == "cuda"
    assert torch.allclose(gpu.cpu(), cpu, atol=1e-9, rtol=0)
    assert torch.allclose(on_input.cpu(), cpu, atol=1e-9, rtol=0)


@cuda
@needs_cuda
def test_torch_simulator_cuda_within_monte_carlo_error(tiger, controllers):
    rollouts = 4000
    cpu = simulate(tiger, controllers, rollouts, torch.Generator().manual_seed(1), backend="torch")
    gpu = simulate(tiger, controllers, rollouts, torch.Generator(device="cuda").manual_seed(1), backend="torch")
    assert gpu.device.type == "cuda" and gpu.shape == cpu.shape
    gpu = gpu.cpu()
    se = ((cpu.var(1) + gpu.var(1)) / rollouts).sqrt()  # standard error of the difference of the two means
    assert ((cpu.mean(1) - gpu.mean(1)).abs() <= 4 * se + 1e-12).all()


@cuda
@needs_cuda
@pytest.mark.parametrize(
    "env",
    [DisasterRelief(), PackageDelivery(), PackageDelivery(successor_rule=True)],
    ids=["disaster_relief", "package_delivery", "package_delivery_successors"],
)
def test_domain_oracles_cuda_within_monte_carlo_error(env):
    rollouts, ctrl = 2000, _domain_controllers(env)
    cpu = simulate(env, ctrl, rollouts, torch.Generator().manual_seed(1), backend="torch")
    gpu = simulate(env, ctrl, rollouts, torch.Generator(device="cuda").manual_seed(1), backend="torch")
    assert gpu.device.type == "cuda"
    gpu = gpu.cpu()
    se = ((cpu.var(1) + gpu.var(1)) / rollouts).sqrt()
    assert ((cpu.mean(1) - gpu.mean(1)).abs() <= 4 * se + 1e-12).all()
