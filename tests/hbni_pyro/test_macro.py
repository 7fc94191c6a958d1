"""Macro-observation processes, their characterisation and the sampled model."""

from __future__ import annotations

import math

import pytest
import torch

from hbni_pyro import (
    HBNIFilter,
    HBNIPosterior,
    MacroObservationModel,
    MacroObservationProcess,
    MaxOfMeanFilter,
    StaticStateBayesFilter,
    VotingFilter,
    characterize,
    decide,
    sample_outputs,
)

from hbni_stubs import DT, THETA, DrawsPosterior


def scattered_posterior(num=300, seed=1):
    g = torch.Generator().manual_seed(seed)
    return DrawsPosterior(THETA * torch.exp(0.4 * torch.randn(num, 3, generator=g, dtype=DT)))


def toy_streams(num, length, seed=0):
    g = torch.Generator().manual_seed(seed)
    classes = torch.randint(0, 3, (num, 1), generator=g).expand(num, length)
    return sample_outputs(THETA, classes, g)


# -- the process --------------------------------------------------------------------------------


def test_stops_at_the_first_frame_over_the_threshold_and_reads_no_further():
    o = torch.tensor([0.7, 0.2, 0.1], dtype=DT)  # SSBF after n frames: 0.7^n / (0.7^n + 0.2^n + 0.1^n)
    first = next(n for n in range(1, 20) if 0.7**n / (0.7**n + 0.2**n + 0.1**n) >= 0.95)
    assert first == 3
    read = []

    def stream():
        for i in range(100):
            read.append(i)
            yield o

    result = MacroObservationProcess(StaticStateBayesFilter(3), threshold=0.95, max_frames=10).run(stream())
    assert (result.label, result.frames_used, result.timed_out) == (0, 3, False)
    assert result.confidence == pytest.approx(0.7**3 / (0.7**3 + 0.2**3 + 0.1**3), rel=1e-12)
    assert len(read) == 3


def test_frame_budget_and_short_streams_time_out():
    flat = torch.full((30, 3), 1 / 3, dtype=DT)
    process = MacroObservationProcess(MaxOfMeanFilter(3), threshold=0.9, max_frames=7)
    assert tuple(process(flat)) == (0, pytest.approx(1 / 3), 7, True)
    assert tuple(process(flat[:4])) == (0, pytest.approx(1 / 3), 4, True)
    batch = process.run_batch(torch.stack([flat, flat]))
    assert batch.frames_used.tolist() == [7, 7] and batch.timed_out.tolist() == [True, True]
    assert process.run_batch(flat[:4].unsqueeze(0)).frames_used.tolist() == [4]


def test_threshold_one_and_voting_stop_at_the_first_frame():
    process = MacroObservationProcess(VotingFilter(3), threshold=1.0, max_frames=5)
    result = process([[0.2, 0.5, 0.3], [0.9, 0.05, 0.05]])
    assert (result.label, result.confidence, result.frames_used, result.timed_out) == (1, 1.0, 1, False)


@pytest.mark.parametrize(
    "make_filter",
    [
        VotingFilter,
        MaxOfMeanFilter,
        StaticStateBayesFilter,
        lambda M: HBNIFilter(scattered_posterior()),
        lambda M: HBNIFilter(scattered_posterior(), "plugin"),
    ],
    ids=["voting", "max_of_mean", "ssbf", "hbni", "hbni_plugin"],
)
@pytest.mark.parametrize("max_frames", [6, 40])
def test_batched_process_agrees_with_the_streaming_process(make_filter, max_frames):
    obs = toy_streams(60, 20, seed=2)
    process = MacroObservationProcess(make_filter(3), threshold=0.97, max_frames=max_frames)
    batch = process.run_batch(obs)
    for b in range(60):
        single = process.run(obs[b])
        assert single.label == int(batch.label[b])
        assert single.confidence == float(batch.confidence[b])
        assert single.frames_used == int(batch.frames_used[b])
        assert single.timed_out == bool(batch.timed_out[b])
    assert int(batch.frames_used.max()) <= min(20, max_frames)


@pytest.mark.parametrize(
    "make_filter",
    [MaxOfMeanFilter, StaticStateBayesFilter, lambda M: HBNIFilter(scattered_posterior())],
    ids=["max_of_mean", "ssbf", "hbni"],
)
def test_several_thresholds_at_once_agree_with_a_process_at_each(make_filter):
    """One evaluation of the filter serves every threshold, the highest first or not: each result is the process's
    own at that threshold, field by field."""
    obs = toy_streams(60, 20, seed=4)
    filt = make_filter(3)
    thresholds = [0.9, 0.5, 0.999, 0.97, 0.9]
    batches = MacroObservationProcess(filt, threshold=0.6, max_frames=12).run_thresholds(obs, thresholds)
    assert len(batches) == len(thresholds)
    for t, batch in zip(thresholds, batches):
        alone = MacroObservationProcess(filt, threshold=t, max_frames=12).run_batch(obs)
        for field in batch._fields:
            assert torch.equal(getattr(batch, field), getattr(alone, field)), (t, field)
    assert MacroObservationProcess(filt).run_thresholds(obs, []) == []
    with pytest.raises(ValueError, match=r"thresholds\[1\]"):
        MacroObservationProcess(filt).run_thresholds(obs, [0.9, 1.5])


def test_process_errors():
    with pytest.raises(TypeError, match="filter"):
        MacroObservationProcess("ssbf")
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="threshold"):
            MacroObservationProcess(StaticStateBayesFilter(3), threshold=bad)
    for bad in (True, "0.9"):  # not numbers
        with pytest.raises(TypeError, match="threshold"):
            MacroObservationProcess(StaticStateBayesFilter(3), threshold=bad)
    for bad in (0, -3):
        with pytest.raises(ValueError, match="max_frames"):
            MacroObservationProcess(StaticStateBayesFilter(3), max_frames=bad)
    for bad in (2.5, True):  # not ints
        with pytest.raises(TypeError, match="max_frames"):
            MacroObservationProcess(StaticStateBayesFilter(3), max_frames=bad)
    process = MacroObservationProcess(StaticStateBayesFilter(3))
    with pytest.raises(ValueError, match="empty"):
        process.run(iter([]))
    with pytest.raises(ValueError, match=r"\(N, M\)"):
        process.run(torch.full((2, 2, 3), 1 / 3))
    with pytest.raises(ValueError, match="width M = 3"):
        process.run([[0.5, 0.5]])
    with pytest.raises(ValueError, match=r"\(B, N, M\)"):
        process.run_batch(torch.full((2, 3), 1 / 3))


# -- characterisation ---------------------------------------------------------------------------


def test_characterize_tables_are_distributions_and_seeded():
    process = MacroObservationProcess(StaticStateBayesFilter(3), threshold=0.95, max_frames=12)
    model = characterize(process, THETA, num_streams=400, seed=3)
    assert model.num_classes == 3 and model.max_frames == 12
    torch.testing.assert_close(model.confusion.sum(1), torch.ones(3, dtype=DT), rtol=0, atol=1e-12)
    torch.testing.assert_close(model.frames_pmf.sum(1), torch.ones(3, dtype=DT), rtol=0, atol=1e-12)
    again = characterize(process, THETA, num_streams=400, seed=3)
    assert torch.equal(model.joint, again.joint)
    assert not torch.equal(model.joint, characterize(process, THETA, num_streams=400, seed=4).joint)
    # counts are multiples of 1 / num_streams
    assert torch.allclose(model.joint * 400, (model.joint * 400).round(), atol=1e-9)


def test_characterize_voting_matches_the_one_frame_argmax_law():
    """Voting stops after one frame, so P(label | c) is P(argmax o = label | c); compared with an
    independent simulation through torch.distributions.Dirichlet. Each of the 9 cells is within
    5 standard errors of the difference of two proportions (4000 streams each)."""
    n = 4000
    model = characterize(MacroObservationProcess(VotingFilter(3), max_frames=5), THETA, num_streams=n, seed=0)
    assert torch.equal(model.frames_pmf[:, 0], torch.ones(3, dtype=DT))
    torch.manual_seed(0)
    for c in range(3):
        o = torch.distributions.Dirichlet(1 + THETA[c] * torch.eye(3, dtype=DT)[c]).sample((n,))
        ref = torch.bincount(decide(o), minlength=3).to(DT) / n
        p = model.confusion[c]
        se = torch.sqrt((p * (1 - p) + ref * (1 - ref)) / n)
        assert ((p - ref).abs() <= 5 * se + 1e-12).all(), (c, p, ref)


def test_characterize_from_a_posterior_predictive_and_errors():
    post = scattered_posterior(50)
    process = MacroObservationProcess(HBNIFilter(post), max_frames=8)
    model = characterize(process, post, num_streams=100, seed=0)
    assert model.info["generative"] == "posterior predictive"
    torch.testing.assert_close(model.confusion.sum(1), torch.ones(3, dtype=DT), rtol=0, atol=1e-12)
    real = HBNIPosterior(
        {
            "theta": post.theta_draws().reshape(2, 25, 3),
            "kappa": torch.ones(2, 25, dtype=DT),
            "gamma": torch.ones(2, 25, dtype=DT),
        },
        torch.full((3,), 1 / 3, dtype=DT),
    )
    assert torch.equal(characterize(process, real, num_streams=100, seed=0).joint, model.joint)
    with pytest.raises(TypeError, match="process"):
        characterize(StaticStateBayesFilter(3), THETA, 10, 0)
    with pytest.raises(ValueError, match="num_streams"):
        characterize(process, THETA, 0, 0)
    with pytest.raises(ValueError, match="3 classes"):
        characterize(process, torch.ones(4, dtype=DT), 10, 0)
    with pytest.raises(ValueError, match="> 0"):
        characterize(process, -THETA, 10, 0)
    with pytest.raises(ValueError, match=r"shape \(M,\)"):
        characterize(process, THETA.unsqueeze(0), 10, 0)
    with pytest.raises(TypeError, match="generative"):
        characterize(process, "theta", 10, 0)


# -- the model: sampling, storage ---------------------------------------------------------------


def small_model():
    joint = torch.zeros(2, 2, 3, dtype=DT)
    joint[0, 0, 0], joint[0, 0, 2], joint[0, 1, 1] = 0.5, 0.2, 0.3
    joint[1, 1, 0], joint[1, 0, 2] = 0.9, 0.1
    return MacroObservationModel(joint, torch.tensor([0.2, 0.1], dtype=DT), {"threshold": 0.95})


def test_sample_follows_the_joint_table():
    """Cell frequencies of 40000 draws per class are within 5 binomial standard errors of the table,
    and empty cells are never drawn (so label and frames keep their dependence)."""
    model = small_model()
    n = 40000
    true = torch.tensor([0, 1]).repeat_interleave(n)
    label, frames = model.sample(true, torch.Generator().manual_seed(0))
    assert label.dtype == frames.dtype == torch.long and label.shape == frames.shape == (2 * n,)
    for c in range(2):
        rows = true == c
        cells = torch.bincount(label[rows] * 3 + frames[rows] - 1, minlength=6).to(DT) / n
        p = model.joint[c].reshape(-1)
        assert ((cells - p).abs() <= 5 * torch.sqrt(p * (1 - p) / n)).all()
    assert model.confusion.tolist() == [[0.7, 0.3], [0.1, 0.9]]
    torch.testing.assert_close(model.mean_frames, torch.tensor([0.5 + 0.6 + 0.6, 0.9 + 0.3], dtype=DT))


def test_sample_is_seeded_keeps_shape_and_validates():
    model = small_model()
    true = torch.tensor([[0, 1, 1], [1, 0, 0]])
    a = model.sample(true, torch.Generator().manual_seed(5))
    b = model.sample(true, torch.Generator().manual_seed(5))
    assert a[0].shape == (2, 3) and torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    with pytest.raises(TypeError, match="generator"):
        model.sample(true, 5)
    with pytest.raises(TypeError, match="true_class"):
        model.sample(torch.tensor([0.0, 1.0]), torch.Generator())
    with pytest.raises(ValueError, match=r"\[0, 2\)"):
        model.sample(torch.tensor([0, 2]), torch.Generator())


def test_model_constructor_rejects_bad_tables():
    good = small_model().joint
    with pytest.raises(ValueError, match="joint"):
        MacroObservationModel(good[0], torch.zeros(2))
    with pytest.raises(ValueError, match="sum to 1"):
        MacroObservationModel(good * 2, torch.zeros(2))
    with pytest.raises(ValueError, match="non-negative"):
        MacroObservationModel(-good, torch.zeros(2))
    with pytest.raises(ValueError, match="timed_out"):
        MacroObservationModel(good, torch.tensor([0.1, 1.5]))


def test_save_load_round_trip_and_foreign_files(tmp_path):
    model = small_model()
    path = model.save(tmp_path / "macro.safetensors")
    back = MacroObservationModel.load(path)
    assert torch.equal(back.joint, model.joint) and torch.equal(back.timed_out, model.timed_out)
    assert back.info == model.info and back.num_classes == 2
    gen = torch.Generator().manual_seed(1)
    assert torch.equal(
        back.sample(torch.tensor([0, 1, 1]), gen)[0],
        model.sample(torch.tensor([0, 1, 1]), torch.Generator().manual_seed(1))[0],
    )
    post = HBNIPosterior(
        {
            "theta": torch.ones(1, 2, 3, dtype=DT),
            "kappa": torch.ones(1, 2, dtype=DT),
            "gamma": torch.ones(1, 2, dtype=DT),
        },
        torch.full((3,), 1 / 3, dtype=DT),
    )
    post.save(tmp_path / "post.safetensors")
    with pytest.raises(
        ValueError, match="holds hbni_pyro.HBNIPosterior, expected a saved hbni_pyro.MacroObservationModel"
    ):
        MacroObservationModel.load(tmp_path / "post.safetensors")
    (tmp_path / "junk").write_bytes(b"\x00" * 5 + b"not a model")
    with pytest.raises(ValueError, match="not a readable"):
        MacroObservationModel.load(tmp_path / "junk")
    with pytest.raises(FileNotFoundError):
        MacroObservationModel.load(tmp_path / "missing")
    assert math.isclose(float(back.accuracy[1]), 0.9)
