"""The numeric boundary: every bad number, seed or generator given to the public API is refused before any work,
with a ``TypeError`` or ``ValueError`` whose message names the argument (never an error from inside torch or NumPy,
never torch's global random stream), and configs refuse what their experiments cannot run when composed."""

from __future__ import annotations

import math

import pytest
import torch

import hbni_pyro
from decpomdp import (
    DisasterRelief,
    PlannerConfig,
    RolloutScorer,
    evaluate,
    monte_carlo_search,
    plan,
    random_controllers,
)
from decpomdp import simulate, solve
from decpomdp.domains.disaster_relief import greedy_controller
from experiments.schemas import build_settings, compose_config
from hbni_infra.checks import as_generator, as_seed
from hbni_infra.counter_random import draw_seed
from hbni_infra.streams import torch_generator
from hbni_pyro import (
    HBNIPosterior,
    reliability,
    run_sbc,
    sample_dirichlet,
    sample_outputs,
    sample_sequences,
    threshold_checks,
)
from hbni_pyro.distributions import gamma_variates, sample_gaussian
from hbni_pyro.models.paper.program import prior_theta_log_density

NAN, INF = math.nan, math.inf
THETA = torch.tensor([1.0, 6.0, 20.0], dtype=torch.float64)


def _g() -> torch.Generator:
    return torch.Generator().manual_seed(0)


def _posterior() -> HBNIPosterior:
    """A small paper-model posterior (2 chains x 20 draws of 3 classes), built without fitting."""
    g = _g()
    theta = gamma_variates(torch.full((2, 20, 3), 4.0), 2.0, g)
    kappa, gamma = gamma_variates(torch.full((2, 20), 2.0), 1.0, g), gamma_variates(torch.full((2, 20), 10.0), 1.0, g)
    return HBNIPosterior({"theta": theta, "kappa": kappa, "gamma": gamma}, torch.full((3,), 1 / 3, dtype=torch.float64))


POST = _posterior()
ENV, CTRL = DisasterRelief(), greedy_controller(2)
OBS = sample_outputs(THETA, torch.arange(3).repeat_interleave(4), _g())
STREAMS = sample_outputs(THETA, torch.zeros(4, 6, dtype=torch.long), _g())
CONF_, CORRECT = torch.rand(20, generator=_g()), torch.rand(20, generator=_g()) > 0.5
LOC, COV = torch.zeros(3, 2, dtype=torch.float64), torch.eye(2, dtype=torch.float64).expand(3, 2, 2)


def _fit(**kwargs):
    return hbni_pyro.fit(OBS, num_chains=1, num_samples=2, warmup_steps=0, progress=False, **kwargs)


# (id, call, exception type, the argument its message names)
CASES = [
    # the generative samplers
    ("outputs classes too high", lambda: sample_outputs(THETA, torch.tensor([3]), _g()), ValueError, "classes"),
    ("outputs classes negative", lambda: sample_outputs(THETA, torch.tensor([-1]), _g()), ValueError, "classes"),
    ("outputs classes fractional", lambda: sample_outputs(THETA, torch.tensor([0.5]), _g()), TypeError, "classes"),
    ("outputs theta a string", lambda: sample_outputs("abc", torch.tensor([0]), _g()), TypeError, "theta"),
    (
        "outputs theta one class",
        lambda: sample_outputs(torch.tensor([1.0]), torch.tensor([0]), _g()),
        ValueError,
        "theta",
    ),
    ("outputs generator None", lambda: sample_outputs(THETA, torch.tensor([0]), None), TypeError, "generator"),
    ("outputs generator a seed", lambda: sample_outputs(THETA, torch.tensor([0]), 0), TypeError, "generator"),
    ("outputs generator a str", lambda: sample_outputs(THETA, torch.tensor([0]), "cpu"), TypeError, "generator"),
    ("gamma scale negative", lambda: gamma_variates(torch.ones(2), -1.0, _g()), ValueError, "scale"),
    ("gamma scale NaN", lambda: gamma_variates(torch.ones(2), NAN, _g()), ValueError, "scale"),
    ("gamma shape zero", lambda: gamma_variates(torch.zeros(2), 1.0, _g()), ValueError, "shape"),
    ("gamma generator None", lambda: gamma_variates(torch.ones(2), 1.0, None), TypeError, "generator"),
    ("dirichlet alpha zero", lambda: sample_dirichlet(torch.tensor([0.0, 1.0]), _g()), ValueError, "alpha"),
    ("dirichlet alpha inf", lambda: sample_dirichlet(torch.tensor([INF, 1.0]), _g()), ValueError, "alpha"),
    ("gaussian loc NaN", lambda: sample_gaussian(torch.tensor([NAN, 0.0]), torch.eye(2), _g()), ValueError, "loc"),
    ("gaussian cov not PD", lambda: sample_gaussian(torch.zeros(2), -torch.eye(2), _g()), ValueError, "cov"),
    ("gaussian cov shape", lambda: sample_gaussian(torch.zeros(2), torch.eye(3), _g()), ValueError, "cov"),
    ("sequences num_frames 0", lambda: sample_sequences(LOC, COV, COV[0], [0], 0, _g()), ValueError, "num_frames"),
    (
        "sequences correlation 1",
        lambda: sample_sequences(LOC, COV, COV[0], [0], 3, _g(), 1.0),
        ValueError,
        "correlation",
    ),
    ("sequences classes", lambda: sample_sequences(LOC, COV, COV[0], [5], 3, _g()), ValueError, "classes"),
    ("torch_generator seed -1", lambda: torch_generator(-1), ValueError, "seed"),
    # the posterior
    ("summary prob 1.5", lambda: POST.summary(prob=1.5), ValueError, "prob"),
    ("summary prob 0", lambda: POST.summary(prob=0), ValueError, "prob"),
    ("summary prob 1", lambda: POST.summary(prob=1), ValueError, "prob"),
    ("summary prob NaN", lambda: POST.summary(prob=NAN), ValueError, "prob"),
    ("summary prob a str", lambda: POST.summary(prob="0.9"), TypeError, "prob"),
    ("summary prob a bool", lambda: POST.summary(prob=True), TypeError, "prob"),
    ("posterior outputs seed -1", lambda: POST.sample_outputs(0, 2, seed=-1), ValueError, "seed"),
    ("posterior outputs seed 2**64", lambda: POST.sample_outputs(0, 2, seed=2**64), ValueError, "seed"),
    ("posterior outputs seed 1.5", lambda: POST.sample_outputs(0, 2, seed=1.5), TypeError, "seed"),
    ("posterior streams generator int", lambda: POST.sample_streams(0, 2, 2, generator=3), TypeError, "generator"),
    ("posterior streams generator str", lambda: POST.sample_streams(0, 2, 2, generator="g"), TypeError, "generator"),
    # fitting
    ("fit seed -1", lambda: _fit(seed=-1), ValueError, "seed"),
    ("fit seed 2**63", lambda: _fit(seed=2**63), ValueError, "seed"),
    ("fit seed 2**70", lambda: _fit(seed=2**70), ValueError, "seed"),
    ("fit seed 1.5", lambda: _fit(seed=1.5), TypeError, "seed"),
    ("fit seed True", lambda: _fit(seed=True), TypeError, "seed"),
    ("fit nuts seed 2**32", lambda: _fit(seed=2**32, method="nuts"), ValueError, "seed"),
    ("fit_many seed -5", lambda: hbni_pyro.fit_many(OBS[None], seed=-5, progress=False), ValueError, "seed"),
    ("check seed -1", lambda: hbni_pyro.predictive_check(POST, OBS, seed=-1), ValueError, "seed"),
    (
        "prior density num_mc 0",
        lambda: prior_theta_log_density(THETA, hbni_pyro.HyperPrior(), num_mc=0),
        ValueError,
        "num_mc",
    ),
    (
        "prior density seed -1",
        lambda: prior_theta_log_density(THETA, hbni_pyro.HyperPrior(), seed=-1),
        ValueError,
        "seed",
    ),
    ("sbc num_datasets 0", lambda: run_sbc("paper", 0), ValueError, "num_datasets"),
    ("sbc thin 0", lambda: run_sbc("paper", 1, thin=0), ValueError, "thin"),
    ("sbc seed -1", lambda: run_sbc("paper", 1, seed=-1), ValueError, "seed"),
    ("sbc num_bins 1", lambda: run_sbc("paper", 1, num_bins=1), ValueError, "num_bins"),
    # calibration
    ("reliability num_bins 0", lambda: reliability(CONF_, CORRECT, num_bins=0), ValueError, "num_bins"),
    ("reliability num_bins 2.5", lambda: reliability(CONF_, CORRECT, num_bins=2.5), TypeError, "num_bins"),
    ("reliability low NaN", lambda: reliability(CONF_, CORRECT, low=NAN), ValueError, "low"),
    ("reliability low 1", lambda: reliability(CONF_, CORRECT, low=1.0), ValueError, "low"),
    (
        "threshold_checks a str",
        lambda: threshold_checks(hbni_pyro.HBNIFilter(POST), STREAMS, torch.zeros(4), thresholds=("a",)),
        TypeError,
        "thresholds[0]",
    ),
    (
        "threshold_checks 1.5",
        lambda: threshold_checks(hbni_pyro.HBNIFilter(POST), STREAMS, torch.zeros(4), thresholds=(0.9, 1.5)),
        ValueError,
        "thresholds[1]",
    ),
    (
        "threshold_checks max_frames 0",
        lambda: threshold_checks(hbni_pyro.HBNIFilter(POST), STREAMS, torch.zeros(4), max_frames=0),
        ValueError,
        "max_frames",
    ),
    # simulation and planning
    ("simulate generator 0", lambda: simulate(ENV, CTRL, 4, 0), TypeError, "generator"),
    ("simulate generator None", lambda: simulate(ENV, CTRL, 4, None), TypeError, "generator"),
    ("simulate torch generator None", lambda: simulate(ENV, CTRL, 4, None, backend="torch"), TypeError, "generator"),
    ("simulate rollouts 0", lambda: simulate(ENV, CTRL, 0, _g()), ValueError, "rollouts_per_controller"),
    ("simulate rollouts 2.5", lambda: simulate(ENV, CTRL, 2.5, _g()), TypeError, "rollouts_per_controller"),
    ("evaluate generator None", lambda: evaluate(ENV, CTRL, 4, None), TypeError, "generator"),
    ("evaluate torch generator 0", lambda: evaluate(ENV, CTRL, 4, 0, backend="torch"), TypeError, "generator"),
    ("evaluate rollouts 1", lambda: evaluate(ENV, CTRL, 1, _g()), ValueError, "rollouts"),
    (
        "random controllers generator None",
        lambda: random_controllers(2, num_agents=2, num_nodes=2, num_actions=3, num_obs=2, generator=None),
        TypeError,
        "generator",
    ),
    ("draw_seed None", lambda: draw_seed(None), TypeError, "generator"),
    ("plan seed -1", lambda: plan(RolloutScorer(ENV), PlannerConfig(budget=10), seed=-1), ValueError, "seed"),
    ("plan seed 2**64", lambda: plan(RolloutScorer(ENV), PlannerConfig(budget=10), seed=2**64), ValueError, "seed"),
    (
        "monte carlo seed -1",
        lambda: monte_carlo_search(RolloutScorer(ENV), num_nodes=2, budget=2, rollouts=2, seed=-1),
        ValueError,
        "seed",
    ),
    ("solve seed -1", lambda: solve("dectiger", 3, seed=-1), ValueError, "seed"),
    # the checks themselves
    ("as_seed a float", lambda: as_seed("seed", 0.0), TypeError, "seed"),
    ("as_generator wrong device", lambda: as_generator("generator", _g(), "meta"), ValueError, "generator"),
]


@pytest.mark.parametrize("call, error, name", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_bad_number_is_refused_naming_its_argument(call, error, name):
    with pytest.raises(error) as info:
        call()
    assert str(info.value).startswith(name) or f"{name}:" in str(info.value), str(info.value)


def test_a_theta_below_zero_is_sampled_from_its_dirichlet():
    """theta in (-1, 0) is a valid Dirichlet (concentration theta + 1 in (0, 1)) that the gamma sampler could not
    draw (it looped forever at theta <= -2/3 and was biased above): its mean ``(theta + 1) / (theta + M)`` holds
    within 4 Monte Carlo standard errors."""
    theta, n = torch.tensor([-0.8, 1.0, 2.0], dtype=torch.float64), 40_000
    x = sample_outputs(theta, torch.zeros(n, dtype=torch.long), _g())[:, 0]
    a0 = float(theta[0]) + 1 + 1 + 1  # Dirichlet (0.2, 1, 1): total concentration 2.2
    mean, var = 0.2 / a0, 0.2 * (a0 - 0.2) / (a0**2 * (a0 + 1))
    assert abs(float(x.mean()) - mean) < 4 * math.sqrt(var / n)


def test_meta_parameters_still_draw_shapes_without_a_generator():
    out = sample_outputs(THETA.to("meta"), torch.zeros(4, dtype=torch.long), None)
    assert out.shape == (4, 3) and out.device.type == "meta"


def test_the_same_generator_state_gives_the_same_draws_as_before():
    """The checks draw nothing: a seed gives the draws it gave before them (theta >= 0 takes the same path)."""
    a = sample_outputs(THETA, torch.arange(3), torch.Generator().manual_seed(5))
    b = sample_outputs(THETA, torch.arange(3), torch.Generator().manual_seed(5))
    assert torch.equal(a, b)


def _compose(*overrides: str):
    return compose_config(overrides, return_hydra_config=True)


@pytest.mark.parametrize(
    "experiment, override, key",
    [
        ("hbni_toy", "toy.theta=[inf,6.0,20.0]", "toy.theta"),
        ("hbni_toy", "toy.theta=[1.0,nan,20.0]", "toy.theta"),
        ("hbni_toy", "toy.theta=[1.0,6.0,-inf]", "toy.theta"),
        ("filtering_error", "study.true_theta=[1.0,inf]", "study.true_theta"),
        ("macro_observation", "study.true_theta=[nan,6.0]", "study.true_theta"),
    ],
)
def test_a_config_with_a_non_finite_theta_is_refused_when_composed(experiment, override, key):
    with pytest.raises(ValueError, match=rf"^{key}: expected at least 2 noise levels > 0, all finite"):
        build_settings(_compose(f"experiment={experiment}", override))
