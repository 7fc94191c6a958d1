"""Held-out sequences rendered on demand: the process's outcomes on them are those on the whole sequences."""

import multiprocessing

import numpy as np
import pytest
import torch

import hbni_pyro
from classifiers import FrameClassifier
from classifiers.data import get_conditions, render_images, render_sequence
from experiments.steps.bank import BankBuild, BankSpec, classify_frames
from experiments.steps.on_demand import LENGTHS, OnDemandStreams

CLASSES = ("ambulance", "police_car", "food_crate")
SHAPE = (72, 96)
FRAMES = 20


@pytest.fixture(scope="module")
def classifier(tmp_path_factory):
    images, labels = [], []
    for name in CLASSES:
        snaps = render_images(name, 6, "training", seed=3, shape=SHAPE)
        images += list(snaps)
        labels += [name] * len(snaps)
    clf = FrameClassifier(seed=0).fit(images, labels)
    return clf, clf.save(tmp_path_factory.mktemp("clf") / "clf.safetensors")


def _spec(sequences: int) -> BankSpec:
    return BankSpec(CLASSES, get_conditions("mission"), seed=11, sequences=sequences, frames=FRAMES, shape=SHAPE)


@pytest.mark.parametrize("start, stop", [(0, 4), (4, 8), (8, 20), (19, 20), (7, 9)])
def test_a_block_of_frames_is_those_frames_of_the_whole_sequence(start, stop):
    cond = get_conditions("mission")
    whole = render_sequence("police_car", FRAMES, cond, seed=5, index=2, shape=SHAPE)
    part = render_sequence("police_car", FRAMES, cond, seed=5, index=2, shape=SHAPE, start=start, stop=stop)
    assert part.shape == (stop - start, *SHAPE, 3)
    assert np.array_equal(part, whole[start:stop])


@pytest.mark.parametrize("start, stop", [(-1, 3), (3, 3), (4, 2), (0, FRAMES + 1)])
def test_a_block_outside_the_sequence_is_refused(start, stop):
    with pytest.raises(ValueError, match="start, stop: expected 0 <= start < stop <= n_frames"):
        render_sequence("police_car", FRAMES, "mission", seed=5, shape=SHAPE, start=start, stop=stop)


def _process(threshold: float) -> hbni_pyro.MacroObservationProcess:
    return hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("ssbf", num_classes=3), threshold, FRAMES)


@pytest.fixture(scope="module")
def banks(classifier, tmp_path_factory) -> tuple[torch.Tensor, torch.Tensor]:
    """The bank of 2 sequences per class and a larger one of 6, built whole: ``(3, S, FRAMES, 3)`` outputs each."""
    clf, path = classifier
    root = tmp_path_factory.mktemp("banks")
    return tuple(BankBuild(_spec(n), clf, path, root / str(n), workers=0).result() for n in (2, 6))


def _replay(bank: torch.Tensor, process: hbni_pyro.MacroObservationProcess) -> hbni_pyro.StreamReplay:
    """``process`` replayed on every sequence of ``bank`` ``(3, S, FRAMES, 3)``."""
    return hbni_pyro.StreamReplay(
        process, bank.reshape(-1, FRAMES, 3).double(), torch.arange(3).repeat_interleave(bank.shape[1])
    )


@pytest.mark.parametrize("workers", [0, 1])
def test_outcomes_on_demand_are_those_on_whole_sequences(classifier, banks, workers, monkeypatch):
    """The bank's next sequences, rendered only as far as the process reads them, give the outcomes that a larger
    bank's whole sequences give; each rendered length is one of the blocks' ends, and the frames rendered are
    those of the whole sequences."""
    clf, path = classifier
    process = _process(0.99)  # the crates decide at once, the cars take longer or time out
    held, larger = _replay(banks[0], process), banks[1]
    seen = []  # the new sequences' streams, as the process reads them
    undecided = OnDemandStreams._undecided
    monkeypatch.setattr(
        OnDemandStreams, "_undecided", staticmethod(lambda *args: seen.append(args[2]) or undecided(*args))
    )
    with OnDemandStreams(_spec(2), clf, path, workers) as more:
        replay, rendered = more.replay(process, held, first=2, count=4)
    whole = _replay(larger, process)
    for field in ("label", "frames_used", "timed_out"):
        assert torch.equal(getattr(replay.results, field), getattr(whole.results, field)), field
    assert torch.equal(replay.true_class, whole.true_class)
    assert set(rendered.unique().tolist()) <= {*LENGTHS, FRAMES}
    assert rendered.min() < FRAMES and rendered.max() > LENGTHS[0]  # some stopped early, some read further
    used = replay.results.frames_used.view(3, 6)[:, 2:]
    assert (used <= rendered).all()
    streams = seen[-1]
    assert streams.shape == (3, 4, FRAMES, 3)
    for c in range(3):
        for i in range(4):
            n = int(rendered[c, i])
            torch.testing.assert_close(streams[c, i, :n], larger[c, 2 + i, :n].double())
            assert (streams[c, i, n:] == 1 / 3).all()  # frames never rendered: uniform outputs
    torch.testing.assert_close(classify_frames(clf, _spec(2), 1, 3, 2, 9), larger[1, 3, 2:9])  # a block alone


def test_the_workers_serve_every_replay_until_closed(classifier, banks):
    clf, path = classifier
    process = _process(0.99)
    before = {p.pid for p in multiprocessing.active_children()}
    with OnDemandStreams(_spec(2), clf, path, 1) as more:
        once, _ = more.replay(process, _replay(banks[0], process), first=2, count=1)
        started = {p.pid for p in multiprocessing.active_children()} - before
        twice, _ = more.replay(process, once, first=3, count=1)
        assert len(started) == 1 and {p.pid for p in multiprocessing.active_children()} - before == started
    assert not started & {p.pid for p in multiprocessing.active_children()}  # ended with the block
    whole = _replay(banks[1], process)
    assert torch.equal(twice.results.label, whole.subset(torch.arange(18).view(3, 6)[:, :4].reshape(-1)).results.label)


def test_no_new_sequences_replays_the_held_ones(classifier, banks):
    clf, path = classifier
    held = _replay(banks[0], _process(0.9))
    replay, rendered = OnDemandStreams(_spec(2), clf, path, 0).replay(held.process, held, first=2, count=0)
    assert rendered.shape == (3, 0) and replay.streams_per_class.tolist() == [2, 2, 2]


def test_bad_arguments_are_refused(classifier, banks):
    clf, path = classifier
    with pytest.raises(ValueError, match="workers: expected an int >= 0"):
        OnDemandStreams(_spec(2), clf, path, -1)
    more = OnDemandStreams(_spec(2), clf, path, 0)
    held = _replay(banks[0], _process(0.9))
    with pytest.raises(ValueError, match="pool: expected a replay of this process on 3 classes"):
        more.replay(_process(0.9), held, first=2, count=1)
    with pytest.raises(ValueError, match="first, count: expected ints >= 0"):
        more.replay(held.process, held, first=-1, count=1)


def test_a_replay_that_reads_past_the_rendered_frames_is_refused(classifier, banks, monkeypatch):
    """The replay of all new streams together must decide within each one's rendered frames; a process taken as
    decided too early (here: after the first block) is caught, not replayed on uniform filler frames."""
    clf, path = classifier
    held = _replay(banks[0], _process(0.99))
    monkeypatch.setattr(OnDemandStreams, "_undecided", staticmethod(lambda process, todo, streams, rendered: []))
    with pytest.raises(RuntimeError, match="it read frames it had not read on those undecided alone"):
        OnDemandStreams(_spec(2), clf, path, 0).replay(held.process, held, first=2, count=4)
