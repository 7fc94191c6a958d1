"""The planning models' honesty checks: the distribution check's level and power, and the value test's power."""

import math

import pytest
import torch

import hbni_pyro
from experiments.steps import honesty
from hbni_pyro import sample_outputs

M, FRAMES = 4, 10


def _process(threshold: float = 0.95) -> hbni_pyro.MacroObservationProcess:
    draws = torch.tensor([[3.0] * M], dtype=torch.float64)

    class Posterior:  # the surface HBNIFilter reads
        num_classes = M
        class_prior = torch.full((M,), 1 / M, dtype=torch.float64)

        def theta_draws(self):
            return draws

    return hbni_pyro.MacroObservationProcess(hbni_pyro.HBNIFilter(Posterior()), threshold=threshold, max_frames=FRAMES)


def _streams(theta: float, per_class: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    truth = torch.arange(M).repeat_interleave(per_class)
    return sample_outputs(torch.full((M,), theta, dtype=torch.float64), truth[:, None].expand(-1, FRAMES), g), truth


def test_a_table_of_the_banks_own_streams_passes():
    process = _process()
    streams, truth = _streams(3.0, 40, seed=0)
    replay = hbni_pyro.StreamReplay(process, streams, truth)
    check = honesty.distribution_test(hbni_pyro.tabulate(process, streams, truth), replay, None, seed=0)
    assert check["passed"]
    for e in check["classes"]:
        assert e["accuracy_p"] == pytest.approx(1.0, abs=1e-3) and e["frames_p"] == pytest.approx(1.0, abs=1e-3)
        assert e["accuracy_interval"][0] <= e["bank_accuracy"] <= e["accuracy_interval"][1]
        assert e["frames_interval"][0] <= e["bank_frames"] <= e["frames_interval"][1]


def test_an_optimistic_table_fails():
    """A table from clean streams (theta 12) judged on noisy ones (theta 2): wrong labels and frames show."""
    process = _process()
    clean, clean_truth = _streams(12.0, 400, seed=1)
    table = hbni_pyro.tabulate(process, clean, clean_truth)
    noisy, truth = _streams(2.0, 40, seed=2)
    check = honesty.distribution_test(table, hbni_pyro.StreamReplay(process, noisy, truth), None, seed=0)
    assert not check["passed"]
    assert sum(not e["passed"] for e in check["classes"]) == M


@pytest.mark.parametrize("table_streams", [None, 30])
def test_level_of_the_class_test(table_streams):
    """Under one law behind table and bank, a test at level 0.05 rejects at most 0.05 of the time: over 300
    repetitions the rejection rate stays below 0.05 + 3 binomial s.e."""
    g = torch.Generator().manual_seed(0)
    pmf = torch.tensor([0.1, 0.3, 0.3, 0.2, 0.1], dtype=torch.float64)
    acc, n, reps = 0.9, 40, 300
    rejected = {"accuracy_p": 0, "frames_p": 0}
    for _ in range(reps):
        if table_streams is None:
            table_pmf, table_acc = pmf, acc
        else:
            draws = torch.multinomial(pmf, table_streams, replacement=True, generator=g)
            table_pmf = torch.bincount(draws, minlength=pmf.numel()).double() / table_streams
            table_acc = float((torch.rand(table_streams, generator=g) < acc).double().mean())
        right = torch.rand(n, generator=g) < acc
        frames = torch.multinomial(pmf, n, replacement=True, generator=g) + 1
        e = honesty.class_test(table_pmf, table_acc, right, frames, table_streams, 500, g)
        for key in rejected:
            rejected[key] += e[key] < 0.05
    bound = 0.05 + 3 * math.sqrt(0.05 * 0.95 / reps)
    assert all(count / reps <= bound for count in rejected.values()), rejected


def test_value_test_closed_form_and_the_size_it_asks_for():
    """One-sided: p = Phi(gap), power Phi(delta / se - z_0.95); the size it asks for is the smallest with 80 % power."""
    phi = lambda x: 0.5 * (1 + math.erf(x / math.sqrt(2)))  # noqa: E731
    planned = {"value": 5.0, "stderr": 0.01}
    executed = {
        "value": 4.7,
        "stderr": 0.01,
        "planned_stream_stderr": 0.0,
        "stream_stderr": 0.3,
        "gap_in_total_stderr": -1.0,
    }
    t = honesty.value_test(planned, executed, bank_size=40)
    se = math.sqrt(0.01**2 * 2 + 0.09)
    assert t["total_stderr"] == pytest.approx(se, rel=1e-12)
    assert t["p_value"] == pytest.approx(phi(-1.0), rel=1e-12) and t["passed"] is True
    assert t["power"] == pytest.approx(phi(0.15 / se - 1.6448536269514722), rel=1e-9)
    need = t["sequences_for_target"]
    bigger = dict(executed, stream_stderr=0.3 * math.sqrt(40 / need))
    assert honesty.value_test(planned, bigger, bank_size=int(need))["power"] >= 0.8
    smaller = dict(executed, stream_stderr=0.3 * math.sqrt(40 / (need - 2)))
    assert honesty.value_test(planned, smaller, bank_size=int(need) - 2)["power"] < 0.8
    hopeless = honesty.value_test({"value": 5.0, "stderr": 1.0}, executed, bank_size=40)
    assert math.isinf(hopeless["sequences_for_target"])


def test_value_test_fails_a_shortfall_only():
    """A plan that promises too much fails (gap below -1.645 s.e.); one that delivers more than it promised passes."""
    planned = {"value": 5.0, "stderr": 0.1}
    base = {"value": 5.0, "stderr": 0.1, "planned_stream_stderr": 0.0, "stream_stderr": 0.0}
    for gap, passed in ((-1.7, False), (-1.6, True), (0.0, True), (4.0, True)):
        t = honesty.value_test(planned, dict(base, gap_in_total_stderr=gap), bank_size=40)
        assert t["passed"] is passed, gap
    exact = {"value": 5.0, "stderr": 0.0}  # no error at all: the gap in standard errors is undefined
    same = honesty.value_test(exact, dict(base, stderr=0.0, gap_in_total_stderr=math.nan), 40)
    assert same["p_value"] == 1.0 and same["passed"] and same["power"] == 1.0 and same["sequences_for_target"] == 40.0
    short = honesty.value_test(exact, dict(base, value=4.9, stderr=0.0, gap_in_total_stderr=math.nan), 40)
    assert short["p_value"] == 0.0 and not short["passed"]


def test_distribution_check_rejects_a_table_of_other_classes():
    process = _process()
    streams, truth = _streams(3.0, 5, seed=0)
    table = hbni_pyro.MacroObservationModel(
        torch.full((3, 3, FRAMES), 1 / (3 * FRAMES), dtype=torch.float64), torch.zeros(3)
    )
    with pytest.raises(ValueError, match="replay: expected 3 classes"):
        honesty.distribution_test(table, hbni_pyro.StreamReplay(process, streams, truth), None, seed=0)


def test_reliability_figure_draws_every_process(tmp_path):
    streams, truth = _streams(3.0, 10, seed=0)
    fig = honesty.reliability_figure({"hbni": _process(), "ssbf": _process(0.9)}, streams, truth, {}, 0.95)
    assert len(fig.axes[0].get_legend().get_texts()) == 4  # calibrated, two processes, the threshold
    fig.savefig(tmp_path / "r.png")
    assert (tmp_path / "r.png").stat().st_size > 0


def test_a_table_with_no_error_in_its_streams_is_a_sample_not_a_certainty():
    """A table right in all of its 1000 streams, a bank right in 39 of 40: two-sample, the accuracy p-value is the
    exact null probability of a gap as wide (binomials under the pooled law, summed), within 4 Monte Carlo
    standard errors; taken as exact, the table makes the bank's one error impossible."""
    n, m, replicates = 40, 1000, 4000
    right = torch.ones(n, dtype=torch.bool)
    right[0] = False
    frames = torch.ones(n, dtype=torch.long)
    pmf = torch.tensor([1.0, 0.0], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    sample = honesty.class_test(pmf, 1.0, right, frames, m, replicates, g)["accuracy_p"]
    exact = honesty.class_test(pmf, 1.0, right, frames, None, replicates, g)["accuracy_p"]
    p0 = torch.tensor((m + n - 1) / (m + n), dtype=torch.float64)
    bank = torch.distributions.Binomial(n, p0).log_prob(torch.arange(n + 1, dtype=torch.float64)).exp()
    table = torch.distributions.Binomial(m, p0).log_prob(torch.arange(m + 1, dtype=torch.float64)).exp()
    gap = (torch.arange(n + 1, dtype=torch.float64)[:, None] / n - torch.arange(m + 1, dtype=torch.float64) / m).abs()
    want = float((bank[:, None] * table[None, :] * (gap >= 1 / n - 1e-12)).sum())
    assert 0.01 < want < 0.02  # about (1 - p0^40) p0^1000: above the check's per-test level of 0.05 / 12
    assert abs(sample - want) <= 4 * math.sqrt(want * (1 - want) / replicates) + 1 / (replicates + 1)
    assert exact == pytest.approx(1 / (replicates + 1))  # no null draw is as far out
