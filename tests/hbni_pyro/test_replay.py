"""StreamReplay: draws are the real process run on the drawn stream, uniform over a class's streams."""

import pytest
import torch

import hbni_pyro
from decpomdp import PerceptionModel
from hbni_pyro import sample_outputs

from hbni_stubs import THETA, DrawsPosterior


def _bank(n_per_class=5, frames=8, seed=0):
    truth = torch.arange(3).repeat_interleave(n_per_class)
    g = torch.Generator().manual_seed(seed)
    return sample_outputs(THETA, truth.unsqueeze(-1).expand(-1, frames), g), truth


def _process(kind="hbni"):
    filt = (
        hbni_pyro.HBNIFilter(DrawsPosterior(THETA[None] * torch.tensor([[0.8], [1.0], [1.3]])), temper=0.7)
        if kind == "hbni"
        else hbni_pyro.StaticStateBayesFilter(3)
    )
    return hbni_pyro.MacroObservationProcess(filt, threshold=0.9, max_frames=6)


@pytest.mark.parametrize("kind", ["hbni", "ssbf"])
def test_each_draw_is_the_process_run_on_the_drawn_stream(kind):
    streams, truth = _bank()
    process = _process(kind)
    replay = hbni_pyro.StreamReplay(process, streams, truth)
    assert isinstance(replay, PerceptionModel)
    asked = torch.tensor([0, 2, 1, 1, 0, 2, 2, 0] * 5)
    label, frames, stream = replay.draw(asked, torch.Generator().manual_seed(3))
    assert (truth[stream] == asked).all()  # a stream of the asked class
    for k in range(asked.numel()):
        alone = process.run(streams[stream[k]])  # the streaming path, one stream at a time
        assert (int(label[k]), int(frames[k])) == (alone.label, alone.frames_used)
    again = replay.sample(asked, torch.Generator().manual_seed(3))
    assert torch.equal(again[0], label) and torch.equal(again[1], frames)  # same seed, same draws


def test_draws_are_uniform_over_a_class_and_match_the_table_of_the_bank():
    """Stream frequencies within 5 binomial s.e. of 1/n; the (label, frames) law within 5 s.e. of
    ``tabulate`` on the same streams (n = 30000 draws per class, s.e. = sqrt(p (1 - p) / n))."""
    streams, truth = _bank(n_per_class=7, seed=1)
    process = _process()
    replay = hbni_pyro.StreamReplay(process, streams, truth)
    table = hbni_pyro.tabulate(process, streams, truth)
    n = 30000
    g = torch.Generator().manual_seed(0)
    for c in range(3):
        label, frames, stream = replay.draw(torch.full((n,), c), g)
        freq = torch.bincount(stream, minlength=streams.shape[0])[truth == c].double() / n
        assert ((freq - 1 / 7).abs() < 5 * (1 / 7 * 6 / 7 / n) ** 0.5).all()
        cell = torch.bincount(label * 6 + frames - 1, minlength=18).double().reshape(3, 6) / n
        p = table.joint[c]
        assert ((cell - p).abs() <= 5 * (p * (1 - p) / n).sqrt() + 1e-12).all()
    assert replay.streams_per_class.tolist() == [7, 7, 7]


def test_stream_longer_than_the_budget_and_empty_batch():
    streams, truth = _bank(frames=20)
    replay = hbni_pyro.StreamReplay(_process(), streams, truth)
    assert int(replay.results.frames_used.max()) <= 6
    label, frames = replay.sample(torch.zeros(0, dtype=torch.long), torch.Generator())
    assert label.shape == frames.shape == (0,)


def test_bad_input_is_a_clear_error():
    streams, truth = _bank()
    process = _process("ssbf")
    with pytest.raises(TypeError, match="process: expected a MacroObservationProcess"):
        hbni_pyro.StreamReplay(hbni_pyro.StaticStateBayesFilter(3), streams, truth)
    with pytest.raises(TypeError, match="true_class: expected a 1-D integer tensor"):
        hbni_pyro.StreamReplay(process, streams, truth.double())
    with pytest.raises(ValueError, match=r"streams: expected shape \(15, N, 3\)"):
        hbni_pyro.StreamReplay(process, streams[:, 0], truth)
    with pytest.raises(ValueError, match=r"every class needs a stream; none for \[2\]"):
        hbni_pyro.StreamReplay(process, streams[:10], truth[:10])
    with pytest.raises(ValueError, match=r"true_class: expected classes in \[0, 3\)"):
        hbni_pyro.StreamReplay(process, streams, truth + 1)
    replay = hbni_pyro.StreamReplay(process, streams, truth)
    with pytest.raises(ValueError, match=r"entries must lie in \[0, 3\)"):
        replay.sample(torch.tensor([3]), torch.Generator())
    with pytest.raises(TypeError, match="true_class: expected a long tensor"):
        replay.sample(torch.tensor([0.0]), torch.Generator())
    with pytest.raises(TypeError, match="generator: expected a torch.Generator"):
        replay.sample(torch.tensor([0]), 0)


def test_a_subset_replays_the_same_results_without_running_the_process_again():
    streams, truth = _bank(n_per_class=4)
    replay = hbni_pyro.StreamReplay(_process(), streams, truth)
    index = torch.tensor([11, 0, 0, 5, 9, 3])  # repeats allowed, classes 2, 0, 0, 1, 2, 0
    part = replay.subset(index)
    fresh = hbni_pyro.StreamReplay(_process(), streams[index], truth[index])
    for a, b in zip(part.results, fresh.results):
        assert torch.equal(a, b)
    assert part.streams_per_class.tolist() == [3, 1, 2]
    g1, g2 = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    asked = torch.tensor([0, 1, 2, 2, 0])
    for a, b in zip(part.draw(asked, g1), fresh.draw(asked, g2)):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match=r"index: expected stream indices in \[0, 12\)"):
        replay.subset(torch.tensor([12]))
    with pytest.raises(ValueError, match=r"every class needs a stream; none for \[1, 2\]"):
        replay.subset(torch.tensor([0, 1]))
    with pytest.raises(TypeError, match="index: expected a 1-D integer tensor"):
        replay.subset(torch.tensor([0.0]))


def test_joined_replays_are_the_replay_of_all_their_streams():
    streams, truth = _bank()
    process = _process()
    even, odd = torch.arange(0, 15, 2), torch.arange(1, 15, 2)  # each with streams of every class
    both = hbni_pyro.StreamReplay(process, streams[even], truth[even]).joined(
        hbni_pyro.StreamReplay(process, streams[odd], truth[odd])
    )
    whole = hbni_pyro.StreamReplay(process, streams, truth).subset(torch.cat([even, odd]))
    assert torch.equal(both.true_class, whole.true_class)
    for mine, theirs in zip(both.results, whole.results):
        assert torch.equal(mine, theirs)
    assert both.streams_per_class.tolist() == [5, 5, 5]
    with pytest.raises(ValueError, match="other: expected a StreamReplay of the same process"):
        whole.joined(hbni_pyro.StreamReplay(_process("ssbf"), streams, truth))
