"""Closed-loop evaluation: on the tabulation's own streams it agrees with the table-sampled evaluation."""

import math
import re

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

import hbni_pyro
from decpomdp.domains.disaster_relief import greedy_controller
from experiments.runs.paths import project_root
from experiments.schemas.mission_study import BootstrapBlock
from experiments.steps import closed_loop
from experiments.steps.planning import score
from hbni_pyro import sample_outputs

M, FRAMES = 6, 12


def _domain(repo_root):
    domain = OmegaConf.load(repo_root / "conf" / "domain" / "disaster_relief.yaml")
    domain.wrong_penalty = 1.0
    return domain


def _recorded_streams(per_class: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Correlated streams like a camera's: each stream has its own noise level, and frames come in repeated pairs."""
    g = torch.Generator().manual_seed(seed)
    truth = torch.arange(M).repeat_interleave(per_class)
    theta = torch.rand(truth.numel(), 1, M, generator=g, dtype=torch.float64) * 6 + 0.5
    half = sample_outputs(theta, truth.unsqueeze(-1).expand(-1, FRAMES // 2), g)
    return half.repeat_interleave(2, dim=1), truth


def _process() -> hbni_pyro.MacroObservationProcess:
    draws = torch.tensor([[2.0] * M, [3.0] * M, [5.0] * M], dtype=torch.float64)

    class Posterior:  # the surface HBNIFilter reads
        num_classes = M
        class_prior = torch.full((M,), 1 / M, dtype=torch.float64)

        def theta_draws(self):
            return draws

    return hbni_pyro.MacroObservationProcess(
        hbni_pyro.HBNIFilter(Posterior(), temper=0.6), threshold=0.95, max_frames=FRAMES
    )


def test_closed_loop_matches_the_table_when_the_bank_is_the_tabulations_streams(repo_root):
    """Same streams, same process: the executed value equals the table-sampled one within 3 s.e. of their
    difference (independent rollouts, 2000 each; the two estimate the same expectation)."""
    streams, truth = _recorded_streams(per_class=10, seed=0)
    process = _process()
    table = hbni_pyro.tabulate(process, streams, truth)
    assert 0.3 < float(table.accuracy.mean()) < 0.97  # a process that errs, so the perception matters
    ctrl = greedy_controller(2)
    domain = _domain(repo_root)
    planned = score(instantiate(domain, perception=table), ctrl, 2000, seed=1)
    bank = streams.reshape(M, 10, FRAMES, M)  # (C, S, F, C), the bank layout
    bank_streams, bank_truth = closed_loop.as_streams(bank)
    assert torch.equal(bank_streams, streams) and torch.equal(bank_truth, truth)
    replay = hbni_pyro.StreamReplay(process, bank_streams, bank_truth)
    executed = closed_loop.execute(ctrl, replay, domain, 2000, seed=2)
    diff_se = math.hypot(planned["stderr"], executed["stderr"])
    assert abs(executed["value"] - planned["value"]) < 3 * diff_se
    assert abs(closed_loop.gap(planned, executed)) < 3
    summary = closed_loop.summarise(planned, executed, replay)
    torch.testing.assert_close(torch.tensor(summary["bank_accuracy"], dtype=torch.float64), table.accuracy)
    torch.testing.assert_close(torch.tensor(summary["bank_mean_frames"], dtype=torch.float64), table.mean_frames)


def test_closed_loop_departs_from_a_table_of_other_streams(repo_root):
    """The check has power: a table whose streams are labelled with the wrong class plans a far lower value."""
    streams, truth = _recorded_streams(per_class=10, seed=0)
    process = _process()
    table = hbni_pyro.tabulate(process, streams, (truth + 1) % M)  # every stream filed under the next class
    ctrl = greedy_controller(2)
    domain = _domain(repo_root)
    planned = score(instantiate(domain, perception=table), ctrl, 500, seed=1)
    executed = closed_loop.execute(ctrl, hbni_pyro.StreamReplay(process, streams, truth), domain, 500, seed=2)
    assert closed_loop.gap(planned, executed) > 10


def test_stream_stderr_sees_how_much_the_sequences_differ(repo_root):
    """Bootstrap over sequence indices: zero spread when every sequence is alike, a large one when half of
    them always fool the filter (their labels name the next class), larger still for values from fewer."""
    streams, truth = _recorded_streams(per_class=8, seed=3)
    process = _process()
    alike = streams.reshape(M, 8, FRAMES, M)[:, :1].expand(M, 8, FRAMES, M)
    mixed = streams.reshape(M, 8, FRAMES, M).clone()
    mixed[:, :4] = mixed[:, :4].roll(1, dims=-1)  # class c's outputs point at class c + 1 in sequences 0-3
    boot = BootstrapBlock(replicates=12, rollouts=300)
    ctrl, domain = greedy_controller(2), _domain(repo_root)
    rollout_se = score(
        instantiate(domain, perception=hbni_pyro.tabulate(process, *closed_loop.as_streams(alike))), ctrl, 300, seed=0
    )["stderr"]

    def replay(bank):
        return lambda idx: hbni_pyro.StreamReplay(process, *closed_loop.as_streams(bank[:, idx]))

    none = closed_loop.stream_stderr(ctrl, replay(alike), 8, 8, domain, boot, seed=1)
    much = closed_loop.stream_stderr(ctrl, replay(mixed), 8, 8, domain, boot, seed=1)
    fewer = closed_loop.stream_stderr(ctrl, replay(mixed), 8, 2, domain, boot, seed=1)  # values from 2 sequences
    assert fewer > much
    assert none < rollout_se and much > 5 * rollout_se


def test_report_pieces_and_acceptance():
    entry = {"value": 5.0, "stderr": 0.1}
    common = {
        "stderr": 0.1,
        "planned_stream_stderr": 0.0,
        "stream_stderr": 0.0,
        "oracle": {"value": 5.0, "stderr": 0.1, "gap_in_stderr": 0.3},
    }
    results = {
        "perfect": {
            **entry,
            "executed": {
                **common,
                "value": 5.0,
                "gap_in_stderr": 0.0,
                "gap_in_total_stderr": 0.0,
                "wrong_per_rollout": 0.0,
                "mean_inference_frames": 10.0,
            },
        },
        "hbni": {
            **entry,
            "executed": {
                **common,
                "value": 4.7,
                "gap_in_stderr": -2.1,
                "gap_in_total_stderr": -1.5,
                "planned_stream_stderr": 0.1,
                "wrong_per_rollout": 0.1,
                "mean_inference_frames": 8.0,
                "bank_accuracy": [0.9] * 6,
                "bank_mean_frames": [8.0] * 6,
            },
        },
        "ssbf": {
            **entry,
            "executed": {
                **common,
                "value": 4.0,
                "gap_in_stderr": -7.0,
                "gap_in_total_stderr": -1.6,
                "wrong_per_rollout": 0.5,
                "mean_inference_frames": 4.0,
                "bank_accuracy": [0.7] * 6,
                "bank_mean_frames": [4.0] * 6,
            },
        },
        "hbni_generative": {
            **entry,
            "macro_accuracy": [1.0] * 6,
            "macro_mean_frames": [6.0] * 6,
            "executed": {
                **common,
                "value": 4.6,
                "gap_in_stderr": -3.8,
                "gap_in_total_stderr": -3.2,
                "wrong_per_rollout": 0.1,
                "mean_inference_frames": 8.0,
                "bank_accuracy": [0.9] * 6,
                "bank_mean_frames": [9.0] * 6,
            },
        },
    }
    acc = closed_loop.acceptance(results)
    assert acc["hbni_executed_over_perfect"] == pytest.approx(0.94)
    assert acc["hbni_executed_beats_ssbf_outside_stderr"] is True
    assert acc["hbni_minus_ssbf_executed_in_stderr"] == pytest.approx(0.7 / (0.02**0.5))
    planning = {"perfect": "exact", "hbni": "empirical", "ssbf": "empirical", "hbni_generative": "generative"}
    lines = closed_loop.report_lines(
        results,
        {"hbni": "HBNI"},
        planning,
        {
            "cached": True,
            "sequences_per_class": 40,
            "held_out_sequences_per_class": 16,
            "frames": 30,
            "seed": 3,
            "path": "x",
        },
    )
    text = "\n".join(lines)
    assert "a policy planned on a simulated table draws from 56 per class" in text
    assert "| HBNI | empirical | 5.000 ± 0.100; 0.100 | 4.700 ± 0.100; 0.000 | -2.1 | -1.5 |" in text
    # one-sided at level 0.05: a gap of -1.6 s.e. (p = 0.055) passes, -3.2 fails
    assert "The **empirical** planning model is **honest** here: full gaps hbni -1.5, ssbf -1.6 s.e." in text
    assert "The **generative** planning model is **not honest** here: full gaps hbni_generative -3.2 s.e." in text
    assert (
        "hbni_generative: its table says accuracy 1.000 after 6.0 frames; on its held-out streams the process gets 0.900 "
        "after 9.0" in text
    )
    assert closed_loop.gap({"value": 1.0, "stderr": 0.3}, {"value": 0.5, "stderr": 0.4}) == pytest.approx(-1.0)
    assert closed_loop.gap({"value": 1.0, "stderr": 0.0}, {"value": 0.5, "stderr": 0.3}, 0.4) == pytest.approx(-1.0)
    assert closed_loop.other_model("empirical") == "generative"


@pytest.mark.parametrize(
    "override, message",
    [
        ("mission.planning_model=learned", "mission.planning_model: expected one of ['empirical', 'generative']"),
        ("mission.generative_streams=0", "mission.generative_streams: expected an int >= 1"),
        ("mission.bank.sequences=1", "mission.bank.sequences: expected an int >= 2"),
        ("mission.bank.workers=-1", "mission.bank.workers: expected an int >= 0"),
        ("mission.bank.cache_dir=' '", "mission.bank.cache_dir: expected a directory"),
        ("mission.bootstrap.replicates=1", "mission.bootstrap.replicates: expected an int >= 2"),
    ],
)
def test_bad_loop_settings_fail_before_any_work(override, message):
    from experiments.schemas import build_settings, compose_config

    cfg = compose_config(["experiment=mission", override])
    with pytest.raises(ValueError, match=re.escape(message)):
        build_settings(cfg)


def test_loop_settings_are_read_from_the_mission_config():
    from experiments.schemas import compose_settings

    loop = compose_settings(["experiment=mission_full", "mission.planning_model=generative"]).mission
    assert loop.planning_model == "generative" and loop.bank.sequences == 128 and loop.bank.workers == 2
    assert (
        loop.bootstrap == BootstrapBlock(64, 4000) and loop.bank.cache_path == project_root() / ".cache" / "banks"
    )  # the project's, from anywhere


def test_stream_stderr_removes_the_rollout_noise_without_bias(repo_root):
    """The replicates' variance less their rollout variance estimates the streams' share: with 20 rollouts a
    replicate (rollout noise about as large as the streams' share) it agrees with a reference whose 20 000 rollouts
    leave almost none to remove. Tolerance: 4 s.e. of the difference of two variance estimates, each
    ``sqrt(2 / (R - 1))`` times its replicates' total variance (normal replicate values)."""
    streams, _ = _recorded_streams(per_class=16, seed=5)
    bank = streams.reshape(M, 16, FRAMES, M)
    process = _process()
    pool = hbni_pyro.StreamReplay(process, *closed_loop.as_streams(bank))
    ctrl, domain = greedy_controller(2), _domain(repo_root)

    def of(idx):
        return closed_loop.resampled(pool, M, 16, idx)

    estimates = []
    for replicates, rollouts in ((400, 20), (100, 20_000)):
        se = closed_loop.stream_stderr(ctrl, of, 16, 16, domain, BootstrapBlock(replicates, rollouts), seed=2)
        rollout_var = score(instantiate(domain, perception=pool), ctrl, rollouts, seed=3)["stderr"] ** 2
        estimates.append((se**2, math.sqrt(2 / (replicates - 1)) * (se**2 + rollout_var), rollout_var))
    (few, few_se, few_noise), (many, many_se, many_noise) = estimates
    assert few_noise > many / 2  # with few rollouts the subtraction has much to remove
    assert abs(few - many) < 4 * math.hypot(few_se, many_se), estimates
    assert many > 3 * many_se  # the streams' share is clearly there
