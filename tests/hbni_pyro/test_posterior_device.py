"""An ``HBNIPosterior`` on a device: moved with ``.to``, saved from and loaded onto any device, and its
predictive draws made there. CPU numbers are unchanged; CUDA runs only where it is available."""

import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_outputs

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


@pytest.fixture(scope="module", params=["paper", "sequence"])
def posterior(request):
    g = torch.Generator().manual_seed(0)
    classes = torch.arange(3).repeat_interleave(20)
    obs = sample_outputs(torch.tensor([2.0, 6.0, 12.0], dtype=torch.float64), classes, g)
    ids = torch.arange(12).repeat_interleave(5) if request.param == "sequence" else None
    return hbni_pyro.fit(
        obs,
        classes,
        model=request.param,
        sequence_ids=ids,
        num_chains=2,
        num_samples=30,
        warmup_steps=30,
        progress=False,
    )


def test_to_cpu_is_the_same_posterior_and_draws(posterior):
    moved = posterior.to("cpu")
    assert moved.device == torch.device("cpu") and moved is not posterior
    for k, v in posterior.samples.items():
        assert torch.equal(moved.samples[k], v)
    assert torch.equal(moved.sample_streams(1, 4, 3, seed=7), posterior.sample_streams(1, 4, 3, seed=7))


def test_meta_tensors_keep_every_shape(posterior):
    meta = posterior.to("meta")
    assert meta.device.type == "meta" and meta.model == posterior.model
    assert {k: v.shape for k, v in meta.samples.items()} == {k: v.shape for k, v in posterior.samples.items()}
    assert meta.class_prior.device.type == "meta"


def test_load_onto_a_device_round_trips(posterior, tmp_path):
    path = posterior.save(tmp_path / "p.safetensors")
    back = hbni_pyro.HBNIPosterior.load(path, device="cpu")
    assert back.device == torch.device("cpu")
    for k, v in posterior.samples.items():
        assert torch.equal(back.samples[k], v)


@CUDA
def test_cuda_round_trip_and_predictive_draws(posterior, tmp_path):
    cuda = posterior.to("cuda")
    assert cuda.device.type == "cuda"
    streams = cuda.sample_streams(0, 8, 5, seed=1)
    assert streams.device.type == "cuda" and streams.shape == (8, 5, 3)
    torch.testing.assert_close(streams.sum(-1), torch.ones(8, 5, dtype=torch.float64, device="cuda"))
    back = hbni_pyro.HBNIPosterior.load(cuda.save(tmp_path / "c.safetensors"))
    assert back.device == torch.device("cpu")
    for k, v in posterior.samples.items():
        assert torch.equal(back.samples[k], v)
