"""Posterior predictive checks: they pass on outputs drawn from the posterior itself and fail on a different noise."""

import os
import re
import subprocess
import sys

import pytest
import torch
from hbni_stubs import DT, THETA

import hbni_pyro
from hbni_pyro import PredictiveCheck, sample_dirichlet, sample_outputs
from hbni_pyro.diagnostics import assert_predictive_check_fails, assert_predictive_check_passes

STREAMS, FRAMES = 30, 6  # held-out streams per class, frames per stream
ALPHA = 0.01  # family-wise: a right model fails one seed in 100 at most (Bonferroni over the tests)


def training(seed=0, per_class=24, frames=4):
    """Toy training outputs: ``per_class`` sequences of ``frames`` i.i.d. outputs per class."""
    g = torch.Generator().manual_seed(seed)
    classes = torch.arange(3).repeat_interleave(per_class * frames)
    return sample_outputs(THETA, classes, g), classes, torch.arange(3 * per_class).repeat_interleave(frames)


@pytest.fixture(scope="module", params=["paper", "confusion", "sequence"])
def posterior(request):
    obs, labels, ids = training()
    return hbni_pyro.fit(
        obs,
        labels,
        model=request.param,
        sequence_ids=ids,
        num_chains=4,
        num_samples=100,
        warmup_steps=300,
        seed=0,
        progress=False,
    )


@pytest.fixture(scope="module")
def paper():
    obs, labels, _ = training()
    return hbni_pyro.fit(obs, labels, num_chains=4, num_samples=100, warmup_steps=300, seed=0, progress=False)


def held_out(source, seed):
    """``STREAMS`` streams of ``FRAMES`` frames per class from ``source(true_class, n, frames, generator)``,
    flattened: outputs ``(N, M)``, labels ``(N,)``, sequence ids ``(N,)``."""
    g = torch.Generator().manual_seed(seed)
    streams = torch.cat([source(c, STREAMS, FRAMES, g) for c in range(3)])
    labels = torch.arange(3).repeat_interleave(STREAMS * FRAMES)
    return streams.reshape(-1, 3), labels, torch.arange(3 * STREAMS).repeat_interleave(FRAMES)


def predictive(posterior):
    return lambda c, n, frames, g: posterior.sample_streams(c, n, frames, generator=g)


def test_the_check_passes_on_outputs_from_the_posterior(posterior):
    """Seeds 0..2: each fails with probability <= ALPHA, all three pass but with probability >= 0.97."""
    for seed in range(3):
        outputs, labels, ids = held_out(predictive(posterior), seed)
        result = assert_predictive_check_passes(posterior, outputs, labels, ids, alpha=ALPHA, seed=seed)
        assert result.labelled and [row["class"] for row in result.table] == ["0", "1", "2"]
        assert len(result.p_values) == 3 * 5
        assert_predictive_check_passes(posterior, outputs, None, ids, alpha=ALPHA, seed=seed)


def test_the_check_fails_on_much_noisier_outputs(paper):
    noisier = lambda c, n, frames, g: sample_outputs(THETA / 5, torch.full((n, frames), c), g)  # noqa: E731
    outputs, labels, ids = held_out(noisier, 0)
    result = assert_predictive_check_fails(paper, outputs, labels, ids, alpha=ALPHA)
    assert result.p_values["1: emitted"] < 1e-6 and result.table[1]["emitted_accuracy"] < 0.9
    unlabelled = assert_predictive_check_fails(
        paper, outputs, None, ids, alpha=ALPHA
    )  # frames to threshold alone give it away
    assert not unlabelled.labelled and list(unlabelled.p_values) == ["all: timeouts", "all: frames", "all: confidence"]


def test_the_check_fails_on_correlated_frames_fitted_as_independent(paper):
    """Every frame of a sequence repeats one look (one output, a little symmetric jitter): the paper's model expects
    independent frames to settle a wrong first look, so it predicts neither the timeouts nor the wrong stops."""

    def correlated(c, n, frames, g):
        look = sample_outputs(THETA, torch.full((n, 1), c), g)
        return (look.log() + sample_dirichlet(torch.full((n, frames, 3), 50.0, dtype=DT), g).log()).softmax(-1)

    outputs, labels, ids = held_out(correlated, 0)
    result = assert_predictive_check_fails(paper, outputs, labels, ids, alpha=ALPHA, threshold=0.999)
    assert {"1: timeouts", "1: calibration"} <= set(result.failures(ALPHA))
    assert result.table[1]["timeout_rate"] > 10 * result.table[1]["predicted_timeout_rate"]


def test_one_frame_units_without_sequence_ids(paper):
    outputs, labels, _ = held_out(predictive(paper), 1)
    result = assert_predictive_check_passes(paper, outputs, labels, alpha=ALPHA)
    assert [row["streams"] for row in result.table] == [STREAMS * FRAMES] * 3
    assert (result.frames["observed"] == 1).all() and result.table[0]["p_frames"] == 1.0


def test_the_check_is_seeded(paper):
    outputs, labels, ids = held_out(predictive(paper), 2)
    a, b = (
        hbni_pyro.predictive_check(paper, outputs, labels, ids, seed=5),
        hbni_pyro.predictive_check(paper, outputs, labels, ids, seed=5),
    )
    assert a.p_values == b.p_values and isinstance(a, PredictiveCheck)
    assert hbni_pyro.predictive_check(paper, outputs, labels, ids, seed=6).p_values != a.p_values


def test_figure_is_written(paper, tmp_path):
    outputs, labels, ids = held_out(predictive(paper), 3)
    for labelled in (labels, None):
        result = hbni_pyro.predictive_check(paper, outputs, labelled, ids, max_frames=4)
        fig = result.figure()
        assert len(fig.axes) == (2 if labelled is not None else 1)
        path = result.save_figure(tmp_path / f"check_{labelled is None}.png")
        assert path.exists() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 1000
        assert (result.frames["observed"] <= 4).all()
    assert "threshold 0.95" in result.report()


def test_argument_errors_name_the_argument(paper):
    outputs, labels, ids = held_out(predictive(paper), 4)
    cases = [
        (dict(outputs=outputs[:, :2]), ValueError, "outputs"),
        (dict(labels=labels[:-1]), ValueError, "labels"),
        (dict(labels=torch.full_like(labels, -1)), ValueError, "labels: entry 0 is -1"),
        (dict(labels=torch.arange(len(labels)) % 3), ValueError, "labels: the outputs of sequence 0"),
        (dict(sequence_ids=ids[:-1]), ValueError, "sequence_ids"),
        (dict(sequence_ids=ids.double()), TypeError, "sequence_ids"),
        (dict(threshold=0.0), ValueError, "threshold"),
        (dict(threshold=1.5), ValueError, "threshold"),
        (dict(max_frames=0), ValueError, "max_frames"),
        (dict(max_frames=2.5), TypeError, "max_frames"),
        (dict(seed="a"), TypeError, "seed"),
        (dict(simulations=0), ValueError, "simulations"),
        (dict(filter="hbni"), TypeError, "filter"),
        (dict(filter=hbni_pyro.VotingFilter(2)), ValueError, "filter"),
    ]
    for kwargs, error, match in cases:
        args = dict(outputs=outputs, labels=labels, sequence_ids=ids) | kwargs
        with pytest.raises(error, match=match):
            hbni_pyro.predictive_check(paper, args.pop("outputs"), args.pop("labels"), args.pop("sequence_ids"), **args)
    with pytest.raises(ValueError, match="alpha"):
        hbni_pyro.predictive_check(paper, outputs, labels, ids).passed(0.0)


def test_false_alarms_at_most_alpha_over_seeds(paper):
    """12 held-out sets from the posterior at alpha 0.1: Bonferroni bounds each false alarm's probability by 0.1,
    so 5 or more of 12 has probability < 0.005."""
    alarms = sum(
        not hbni_pyro.predictive_check(paper, *held_out(predictive(paper), 100 + seed), seed=seed).passed(0.1)
        for seed in range(12)
    )
    assert alarms <= 4


def test_docs_python_blocks_run_as_written(repo_root, tmp_path):
    """Each Python block of docs/predictive_checks.md runs alone in a fresh interpreter."""
    blocks = re.findall(r"```python\n(.*?)```", (repo_root / "docs" / "predictive_checks.md").read_text(), re.S)
    assert len(blocks) == 2
    for block in blocks:
        proc = subprocess.run(
            [sys.executable, "-c", block],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            env=os.environ | {"PYTHONPATH": str(repo_root)},
            timeout=300,
        )
        assert proc.returncode == 0, (
            f"this block of docs/predictive_checks.md fails alone:\n{block}\n{proc.stderr[-3000:]}"
        )
    assert (tmp_path / "check.png").stat().st_size > 1000


def test_sequences_of_different_lengths_in_any_order(paper):
    """Sequences of 2 and 7 frames, their ids interleaved: each is one stream, its frames in the order given."""
    g = torch.Generator().manual_seed(7)
    short, long = paper.sample_streams(0, 20, 2, generator=g), paper.sample_streams(2, 20, 7, generator=g)
    outputs = torch.cat([short.reshape(-1, 3), long.reshape(-1, 3)])
    ids = torch.cat([torch.arange(0, 40, 2).repeat_interleave(2), torch.arange(1, 40, 2).repeat_interleave(7)])
    labels = torch.cat([torch.zeros(40, dtype=torch.long), torch.full((140,), 2)])
    result = assert_predictive_check_passes(paper, outputs, labels, ids, alpha=ALPHA, max_frames=5)
    assert [(row["class"], row["streams"]) for row in result.table] == [("0", 20), ("2", 20)]
    assert result.frames["observed"].max() <= 5 and len(result.frames["predicted"]) == 40 * 20
    named = hbni_pyro.HBNIPosterior(paper.samples, paper.class_prior, class_names=("cat", "dog", "owl"))
    assert [row["class"] for row in hbni_pyro.predictive_check(named, outputs, labels, ids).table] == ["cat", "owl"]
