"""Devices across the public entry points of ``hbni_pyro``: the MH fit of every registered noise model, the
posterior's predictive draws and summary, every filter of ``make_filter``, macro-observation processes and their
tables (``characterize``, ``tabulate``), calibration, the temper and ``posterior.check``.

With ``device="cpu"`` every returned tensor is on the CPU and equal to the default path's. ``meta`` tensors
(shapes without values) run the predictive sampler and every filter's ``update`` and ``run``, and build a
``MacroObservationModel``; what needs values cannot run there: MH (``fit`` raises a ``ValueError`` naming
``device``), and a macro-observation process, whose stopping frame depends on the values (so neither
``characterize``, ``tabulate`` nor ``check``). The CUDA tests run only where CUDA is available.
"""

import dataclasses
from typing import Any

import pytest
import torch
from torch import Tensor

import hbni_pyro
from hbni_pyro import model_names, sample_outputs

cuda = pytest.mark.cuda
needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
CPU = torch.device("cpu")
MODELS = model_names()
FILTER_CASES = [("hbni", {}), ("hbni", {"mode": "plugin"}), ("ssbf", {}), ("max_of_mean", {}), ("voting", {})]
# (the calibrated peer's map moves to the filter's device: tests/hbni_pyro/test_frame_calibration.py)
TINY = dict(num_chains=2, num_samples=20, warmup_steps=20, progress=False)


def _tensors(obj: Any) -> list[Tensor]:
    """Every tensor reachable from ``obj`` through dicts, sequences, dataclasses and ``hbni_pyro`` objects."""
    if isinstance(obj, Tensor):
        return [obj]
    if isinstance(obj, dict):
        return [t for v in obj.values() for t in _tensors(v)]
    if isinstance(obj, (list, tuple)):
        return [t for v in obj for t in _tensors(v)]
    if dataclasses.is_dataclass(obj) or type(obj).__module__.startswith("hbni_pyro"):
        return [t for v in vars(obj).values() for t in _tensors(v)]
    return []


def _on(device: str, *results: Any) -> bool:
    tensors = [t for r in results for t in _tensors(r)]
    return bool(tensors) and all(t.device.type == device for t in tensors)


@pytest.fixture(scope="module")
def data() -> dict[str, Tensor]:
    classes = torch.arange(3).repeat_interleave(20)
    obs = sample_outputs(torch.tensor([2.0, 6.0, 12.0], dtype=torch.float64), classes, torch.Generator().manual_seed(0))
    ids = torch.arange(12).repeat_interleave(5)
    return {"obs": obs, "classes": classes, "ids": ids, "labels": torch.where(ids % 3 == 0, classes, -1)}


def _fit(data: dict[str, Tensor], model: str, **kwargs: Any) -> hbni_pyro.HBNIPosterior:
    return hbni_pyro.fit(data["obs"], data["labels"], model=model, sequence_ids=data["ids"], **TINY, **kwargs)


@pytest.fixture(scope="module", params=MODELS)
def posterior(request, data) -> hbni_pyro.HBNIPosterior:
    return _fit(data, request.param, device="cpu")


# ---- fit ----------------------------------------------------------------------------------------------------
def test_fit_on_cpu_equals_the_default(posterior, data):
    default = _fit(data, posterior.model)
    assert posterior.device == CPU and _on("cpu", posterior)
    assert posterior.samples.keys() == default.samples.keys()
    for k, v in default.samples.items():
        assert torch.equal(posterior.samples[k], v)
    assert torch.equal(posterior.label_probs, default.label_probs)
    assert posterior.info["acceptance_rate"] == default.info["acceptance_rate"]
    explicit = _fit(data, posterior.model, device=torch.device("cpu"))
    assert all(torch.equal(explicit.samples[k], v) for k, v in default.samples.items())


def test_fit_many_on_cpu(data):
    sets = torch.stack([data["obs"], data["obs"].flip(0)])
    posteriors = hbni_pyro.fit_many(sets, **TINY, device="cpu")
    assert len(posteriors) == 2 and _on("cpu", posteriors)
    default = hbni_pyro.fit_many(sets, **TINY)
    assert all(torch.equal(a.samples["theta"], b.samples["theta"]) for a, b in zip(posteriors, default))


def test_fit_device_argument_is_checked(data):
    obs = data["obs"]
    with pytest.raises(TypeError, match="device"):
        hbni_pyro.fit(obs, device=0)
    with pytest.raises(ValueError, match="device"):
        hbni_pyro.fit(obs, device="no-such-device")
    with pytest.raises(ValueError, match="device: MH needs values"):
        hbni_pyro.fit(obs, device="meta")
    with pytest.raises(ValueError, match="device: MH needs values.*device of obs"):
        hbni_pyro.fit(obs.to("meta"))
    with pytest.raises(ValueError, match="device: method='nuts' runs on the CPU only"):
        hbni_pyro.fit(obs, method="nuts", device="meta")
    with pytest.raises(ValueError, match="device.*obs_sets"):
        hbni_pyro.fit_many(obs.expand(2, -1, -1).to("meta"))
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="device: device 'cuda' is not available"):
            hbni_pyro.fit(obs, device="cuda")


# ---- posterior: predictive draws and summary ----------------------------------------------------------------
def test_predictive_draws_and_summary_on_cpu(posterior):
    streams = posterior.sample_streams(1, 4, 3, seed=2)
    outputs = posterior.sample_outputs(0, 5, seed=2)
    assert streams.shape == (4, 3, 3) and outputs.shape == (5, 3) and _on("cpu", streams, outputs)
    assert torch.equal(streams, posterior.sample_streams(1, 4, 3, generator=torch.Generator("cpu").manual_seed(2)))
    assert all(row["ess"] > 0 for row in posterior.summary().values())


def test_predictive_draws_on_meta_keep_their_shapes(posterior):
    meta = posterior.to("meta")
    streams, outputs = meta.sample_streams(1, 4, 3, seed=2), meta.sample_outputs(2, 5)
    assert streams.shape == (4, 3, 3) and outputs.shape == (5, 3) and _on("meta", streams, outputs)


# ---- filters ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "options"), FILTER_CASES, ids=[f"{n}{o}" for n, o in FILTER_CASES])
def test_every_filter_on_cpu_equals_the_default(posterior, name, options):
    streams = posterior.sample_streams(2, 3, 4, seed=1)
    default = hbni_pyro.make_filter(name, posterior, **options)
    on_cpu = hbni_pyro.make_filter(name, posterior, device="cpu", **options)
    assert default.device == on_cpu.device == CPU
    beliefs = on_cpu.run(streams)
    updates = torch.stack([on_cpu.update(o) for o in streams[0].tolist()])
    assert _on("cpu", beliefs, updates, on_cpu)
    assert torch.equal(beliefs, default.run(streams))
    torch.testing.assert_close(updates, beliefs[0], rtol=0, atol=1e-12)  # as in test_streaming_equals_batched


@pytest.mark.parametrize(("name", "options"), FILTER_CASES, ids=[f"{n}{o}" for n, o in FILTER_CASES])
def test_every_filter_on_meta_keeps_the_shapes(posterior, name, options):
    meta = hbni_pyro.make_filter(name, posterior.to("meta"), **options)
    assert meta.device.type == "meta"
    update = meta.update(torch.full((3,), 1 / 3))  # a CPU row is moved to the filter's device
    batch = meta.run(torch.empty(2, 4, 3, device="meta"))
    assert update.shape == (3,) and batch.shape == (2, 4, 3) and _on("meta", update, batch)
    assert meta.update(torch.empty(3, device="meta")).shape == (3,) and meta.frames_seen == 2
    with pytest.raises(ValueError, match="width"):  # shape checks still run on meta
        meta.update(torch.empty(4, device="meta"))


def test_filter_device_arguments_are_checked(posterior):
    assert hbni_pyro.make_filter("voting", num_classes=3, device="meta").device.type == "meta"
    moved = hbni_pyro.make_filter("hbni", posterior, device="meta")
    assert moved.device.type == "meta" and _on("meta", moved.draws) and posterior.device == CPU
    with pytest.raises(TypeError, match="device"):
        hbni_pyro.make_filter("ssbf", num_classes=3, device=1)
    with pytest.raises(ValueError, match="device"):
        hbni_pyro.HBNIFilter(posterior, device="no-such-device")


def test_values_are_not_checked_on_meta():
    rows = hbni_pyro.as_outputs(torch.empty(5, 3, device="meta"))
    assert rows.shape == (5, 3) and rows.is_meta
    with pytest.raises(ValueError, match="M >= 2"):
        hbni_pyro.as_outputs(torch.empty(5, 1, device="meta"))
    table = hbni_pyro.MacroObservationModel(torch.empty(3, 3, 4, device="meta"), torch.empty(3))
    assert table.timed_out.is_meta and table.mean_frames.shape == (3,) and table.confusion.shape == (3, 3)
    with pytest.raises(ValueError, match="timed_out: expected shape"):
        hbni_pyro.MacroObservationModel(torch.empty(3, 3, 4, device="meta"), torch.empty(2))


# ---- macro-observations, calibration, temper, checks --------------------------------------------------------
def test_macro_observations_on_cpu(posterior):
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("hbni", posterior, device="cpu"), 0.9, 4)
    streams = torch.cat([posterior.sample_streams(c, 4, 4, seed=c) for c in range(3)])
    truth = torch.arange(3).repeat_interleave(4)
    result = process.run(streams[0])
    assert isinstance(result.label, int) and isinstance(result.confidence, float)
    batch = process.run_batch(streams)
    model = hbni_pyro.characterize(process, posterior, 6, seed=1)
    table = hbni_pyro.tabulate(process, streams, truth)
    drawn = model.sample(truth, torch.Generator().manual_seed(0))
    replay = hbni_pyro.StreamReplay(process, streams, truth)
    assert _on("cpu", batch, model, table, drawn, model.outcomes(), replay.results)
    assert torch.equal(
        model.joint,
        hbni_pyro.characterize(
            hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("hbni", posterior), 0.9, 4), posterior, 6, seed=1
        ).joint,
    )
    calibration = hbni_pyro.stream_reliability(process.filter, streams, truth)
    if posterior.frame_correlation:  # the sequence model counts correlated frames itself: no temper
        with pytest.raises(ValueError, match="counts correlated frames itself"):
            hbni_pyro.fit_temper(posterior, streams, truth, grid=[0.5, 1.0])
        exchangeable = dataclasses.replace(posterior, frame_correlation=0.0)
        temper = hbni_pyro.fit_temper(exchangeable, streams, truth, grid=[0.5, 1.0])
    else:
        temper = hbni_pyro.fit_temper(posterior, streams, truth, grid=[0.5, 1.0])
    assert _on("cpu", calibration, temper)
    assert hbni_pyro.threshold_checks(process.filter, streams, truth, thresholds=(0.9,))["0.9"]["emitted"] >= 0


def test_posterior_check_on_cpu(posterior, data):
    n = 30
    result = hbni_pyro.predictive_check(
        posterior, data["obs"][:n], data["classes"][:n], data["ids"][:n], simulations=2, max_frames=4
    )
    assert _on("cpu", result) and result.p_values
    unlabelled = hbni_pyro.predictive_check(posterior, data["obs"][:n], None, data["ids"][:n], simulations=2)
    assert _on("cpu", unlabelled)


# ---- CUDA ---------------------------------------------------------------------------------------------------
@cuda
@needs_cuda
@pytest.mark.parametrize("model", MODELS)
def test_fit_on_cuda_stays_there(data, model):
    on_input = _fit({k: v.cuda() for k, v in data.items()}, model)
    explicit = _fit(data, model, device="cuda")
    for posterior in (on_input, explicit):
        assert posterior.device.type == "cuda" and _on("cuda", posterior)
        assert all(torch.isfinite(v).all() for v in posterior.samples.values())
    assert on_input.sample_streams(0, 4, 3).device.type == "cuda"


@cuda
@needs_cuda
def test_fit_on_cuda_within_monte_carlo_error_of_the_cpu(data):
    settings = dict(num_chains=8, num_samples=600, warmup_steps=300, progress=False)
    cpu = hbni_pyro.fit(data["obs"], **settings).summary()
    gpu = hbni_pyro.fit(data["obs"], **settings, device="cuda").summary()
    for name, row in cpu.items():
        other = gpu[name]
        se = (row["sd"] ** 2 / row["ess"] + other["sd"] ** 2 / other["ess"]) ** 0.5
        assert abs(row["mean"] - other["mean"]) <= 5 * se, name


@cuda
@needs_cuda
@pytest.mark.parametrize(("name", "options"), FILTER_CASES, ids=[f"{n}{o}" for n, o in FILTER_CASES])
def test_every_filter_on_cuda_matches_the_cpu(posterior, name, options):
    streams = posterior.sample_streams(2, 3, 5, seed=1)
    gpu = hbni_pyro.make_filter(name, posterior.to("cuda"), **options)
    beliefs = gpu.run(streams.cuda())
    update = gpu.update(streams[0, 0])
    assert gpu.device.type == "cuda" and beliefs.device.type == "cuda" and update.device.type == "cuda"
    torch.testing.assert_close(
        beliefs.cpu(), hbni_pyro.make_filter(name, posterior, **options).run(streams), atol=1e-9, rtol=1e-9
    )


@cuda
@needs_cuda
def test_macro_observations_and_checks_on_cuda(posterior, data):
    gpu = posterior.to("cuda")
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("hbni", gpu), 0.9, 4)
    model = hbni_pyro.characterize(process, gpu, 20, seed=1)
    assert _on("cuda", model) and model.sample(torch.arange(3), torch.Generator("cuda").manual_seed(0))[0].is_cuda
    assert _on("cpu", model.outcomes())
    streams = gpu.sample_streams(1, 2, 4, seed=1)
    assert process.run(streams[0]).frames_used >= 1 and _on("cuda", process.run_batch(streams))
    result = hbni_pyro.predictive_check(gpu, data["obs"][:30], data["classes"][:30], data["ids"][:30], simulations=2)
    assert _on("cpu", result)
