"""Simulation-based calibration of every variant's MH kernel on data from its own prior.

Each test fits 100 datasets in one vectorised run and checks, for every rank statistic, a
chi-square test of uniformity of its ranks over 10 bins. The tolerance is Bonferroni over the
statistics at a family-wise false-alarm rate of 1 %: every p-value must exceed 0.01 / (number
of statistics). ``benchmarks/bench_sbc.py`` runs the same check with more datasets.
"""

import pytest

from hbni_pyro import HyperPrior, run_sbc

CASES = {
    # The paper's toy setting: 15 unlabelled outputs per dataset.
    "paper": dict(labelled=False, size=15),
    # Labelled outputs (as in the mission's calibration fits). The default off-diagonal prior keeps the
    # simulated outputs above the validation floor (1e-6); a wide one (sd 2) does not: a concentration
    # near 0.05 puts half of an entry's mass below the floor, and floored data no longer follow the model.
    "confusion": dict(size=30),
    # 12 labelled sequences of 5 frames.
    "sequence": dict(size=12, num_frames=5),
}


@pytest.mark.parametrize("model", sorted(CASES))
def test_sbc_ranks_are_uniform(model):
    result = run_sbc(model, 100, seed=7, **CASES[model])
    assert result.num_draws == 99
    assert all(len(r) == 100 and r.min() >= 0 and r.max() <= 99 for r in result.ranks.values())
    floor = 0.01 / len(result.p_value)
    assert min(result.p_value.values()) > floor, result.p_value


def test_sbc_detects_a_wrong_prior():
    """The check has power: fitting with a prior other than the one the data came from skews the ranks."""
    wrong = run_sbc(
        "paper", 100, labelled=False, size=15, seed=7, fit_hyperprior=HyperPrior(beta=8.0, eta=1.0, nu=8.0, omega=5.0)
    )
    assert min(wrong.p_value.values()) < 1e-4
