"""Noise models are objects: a toy variant added by one module and one ``register`` call runs through
fitting, storage, the filter and the generative tables; the registry's errors."""

import pytest
import torch

import hbni_pyro
from hbni_pyro import NOISE_MODELS, model_names, noise_model, register, sample_outputs
from hbni_pyro.models import unregister
import toy_variant

DT = torch.float64


@pytest.fixture
def frozen():
    spec = register(toy_variant.NOISE_MODEL)
    yield spec
    unregister("frozen")


def data(n=60, seed=0):
    g = torch.Generator().manual_seed(seed)
    labels = torch.arange(3).repeat_interleave(n // 3)
    return sample_outputs(torch.tensor([2.0, 5.0, 9.0], dtype=DT), labels, g), labels


def test_the_built_in_variants_are_registered_specs():
    assert model_names()[:3] == ("paper", "confusion", "sequence")
    assert [noise_model(name).name for name in model_names()] == list(model_names())
    assert noise_model("sequence").sequences and not noise_model("paper").sequences
    assert noise_model(NOISE_MODELS["confusion"]) is NOISE_MODELS["confusion"]


def test_a_registered_variant_fits_stores_filters_and_predicts_as_its_own(frozen, tmp_path):
    obs, labels = data()
    kw = dict(num_chains=4, num_samples=60, warmup_steps=40, seed=3, progress=False)
    post = hbni_pyro.fit(obs, labels, model="frozen", **kw)
    ref = hbni_pyro.fit(obs, labels, model="paper", **kw)
    assert post.model == "frozen" and post.noise_model is frozen
    for k in ref.samples:  # fitting reads the spec's kernel, which is the paper's: the same draws
        assert torch.equal(post.samples[k], ref.samples[k])
    loaded = hbni_pyro.HBNIPosterior.load(post.save(tmp_path / "frozen.safetensors"))
    assert loaded.model == "frozen" and torch.equal(loaded.samples["theta"], post.samples["theta"])
    f = hbni_pyro.make_filter("hbni", loaded)
    assert f.model == "frozen"
    torch.testing.assert_close(
        f.run(obs[None, :5]), hbni_pyro.make_filter("hbni", ref).run(obs[None, :5]), rtol=0, atol=0
    )
    streams = loaded.sample_streams(2, 7, 4, seed=1)  # the spec's own predictive: one output repeated
    assert streams.shape == (7, 4, 3) and torch.equal(streams, streams[:, :1].expand(-1, 4, -1))
    table = hbni_pyro.characterize(
        hbni_pyro.MacroObservationProcess(f, threshold=0.9, max_frames=4), loaded, 50, seed=0
    )
    assert table.info["generative"] == "posterior predictive (frozen model)"
    nuts = hbni_pyro.fit(
        obs,
        labels,
        model=frozen,
        method="nuts",
        num_chains=1,
        num_samples=20,
        warmup_steps=20,
        progress=False,
        jit=False,
    )
    assert nuts.model == "frozen" and set(nuts.samples) == {"theta", "kappa", "gamma"}


def test_a_variant_without_sbc_parts_says_so(frozen):
    from hbni_pyro import run_sbc

    with pytest.raises(ValueError, match="'frozen' noise model has no draw_prior"):
        run_sbc("frozen", 2)


def test_registry_errors(frozen):
    with pytest.raises(ValueError, match="model: expected one of .*'frozen'.*got 'nope'"):
        hbni_pyro.fit(torch.full((4, 3), 1 / 3, dtype=DT), model="nope")
    with pytest.raises(ValueError, match="already registered"):
        register(toy_variant.NOISE_MODEL.__class__(**{**toy_variant.NOISE_MODEL.__dict__}))
    assert register(frozen) is frozen  # registering the same spec twice is harmless
    with pytest.raises(TypeError, match="spec: expected a NoiseModel, got str"):
        register("frozen")
    with pytest.raises(ValueError, match="built-in noise model 'paper' cannot be removed"):
        unregister("paper")
    with pytest.raises(ValueError, match="model: expected one of"):
        unregister("nope")


def test_a_saved_posterior_of_an_unregistered_variant_is_refused(frozen, tmp_path):
    obs, labels = data()
    path = hbni_pyro.fit(
        obs, labels, model="frozen", num_chains=2, num_samples=10, warmup_steps=10, progress=False
    ).save(tmp_path / "p.safetensors")
    unregister("frozen")
    try:
        with pytest.raises(ValueError, match="unknown noise model 'frozen'"):
            hbni_pyro.HBNIPosterior.load(path)
    finally:
        register(toy_variant.NOISE_MODEL)
