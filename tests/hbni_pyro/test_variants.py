"""The confusion-aware and sequence-aware models: closed forms against brute force and Pyro's
enumeration, their kernels under ``pyro.infer.MCMC``, MH against NUTS, recovery, and errors."""

import itertools
import math

import pyro
import pytest
import torch
from pyro import poutine
from pyro.infer import MCMC, TraceEnum_ELBO

import hbni_pyro
from hbni_pyro import (
    ConfusionMetropolis,
    HyperPrior,
    SequenceMetropolis,
    confusion_model,
    sample_dirichlet,
    sequence_model,
)
from hbni_pyro.distributions import concentrations, ilr, ilr_log_jacobian
from hbni_pyro.models import sequence_stats
from hbni_pyro.models.confusion.program import confusion_log_joint, off_diagonal, off_diagonal_values
from hbni_pyro.models.sequence.program import TwoLevelSequence, sequence_log_joint, sequence_prior_log_prob
from hbni_infra.stats import monte_carlo_z
from known_models import ALPHA, DT, LOC, confusion_data, confusion_params, sequence_params, sequences
from nuts_references import load_reference, problems

HP = HyperPrior()


# -- closed forms --------------------------------------------------------------------------------


def test_off_diagonal_round_trip():
    x = torch.arange(12, dtype=DT).reshape(2, 3, 2)
    full = off_diagonal(x)
    assert torch.equal(full.diagonal(dim1=-2, dim2=-1), torch.ones(2, 3, dtype=DT))
    assert torch.equal(off_diagonal_values(full), x)


@pytest.mark.filterwarnings("ignore:TraceEnum_ELBO found no sample sites")
def test_confusion_log_joint_matches_brute_force_and_pyro_enumeration():
    g = torch.Generator().manual_seed(1)
    obs = sample_dirichlet(ALPHA[torch.tensor([0, 1, 2, 0])], g)
    prior = torch.tensor([0.5, 0.3, 0.2], dtype=DT)
    params = confusion_params()
    alpha = concentrations(params["theta"], params["beta"])
    base = confusion_log_joint(obs[:0], params, torch.zeros(0, dtype=torch.long), prior, HP)  # the prior alone
    for labels in (torch.tensor([-1, -1, -1, -1]), torch.tensor([2, -1, 0, -1])):
        terms = []
        for assignment in itertools.product(range(3), repeat=4):
            if any(y >= 0 and a != y for a, y in zip(assignment, labels.tolist())):
                continue
            terms.append(
                sum(
                    prior[m].log() + torch.distributions.Dirichlet(alpha[m]).log_prob(o)
                    for o, m in zip(obs, assignment)
                )
            )
        ref = base + torch.logsumexp(torch.stack(terms), 0)
        torch.testing.assert_close(confusion_log_joint(obs, params, labels, prior, HP), ref, rtol=0, atol=1e-9)
        # Pyro's enumeration over the classes, with the continuous sites fixed (non-centred beta).
        raw = (off_diagonal_values(params["beta"]).log() - params["beta_loc"]) / params["beta_scale"]
        data = {k: params[k] for k in ("theta", "kappa", "gamma", "beta_loc", "beta_scale")} | {"beta_raw": raw}
        conditioned = poutine.condition(confusion_model, data=data)
        pyro.clear_param_store()
        loss = TraceEnum_ELBO(max_plate_nesting=2).loss(conditioned, lambda *a, **k: None, obs, labels, prior, HP)
        log_jac = (off_diagonal_values(params["beta"]).log() + math.log(params["beta_scale"])).sum()  # beta -> beta_raw
        torch.testing.assert_close(torch.tensor(-loss, dtype=DT), ref + log_jac, rtol=0, atol=1e-8)


def test_two_level_sequence_density_is_the_joint_gaussian_of_its_frames():
    obs, classes = sequences(3, 4, seed=2)
    p = sequence_params()
    mask = torch.tensor([[True, True, True, True], [True, True, False, False], [True, True, True, False]])
    ours = TwoLevelSequence(p["loc"][classes], p["between"][classes], p["within"], mask).log_prob(obs)
    for k in range(3):
        y = ilr(obs[k][mask[k]])
        n = y.shape[0]
        cov = torch.kron(torch.eye(n, dtype=DT), p["within"]) + torch.kron(
            torch.ones(n, n, dtype=DT), p["between"][classes[k]]
        )
        ref = torch.distributions.MultivariateNormal(p["loc"][classes[k]].repeat(n), cov).log_prob(y.reshape(-1))
        torch.testing.assert_close(ours[k], ref + ilr_log_jacobian(obs[k][mask[k]]).sum(), rtol=0, atol=1e-9)


@pytest.mark.filterwarnings("ignore:TraceEnum_ELBO found no sample sites")
def test_sequence_log_joint_matches_brute_force_and_pyro_enumeration():
    obs, _ = sequences(3, 4, seed=3)
    mask = torch.ones(3, 4, dtype=torch.bool)
    prior = torch.tensor([0.2, 0.5, 0.3], dtype=DT)
    p = sequence_params()
    flat = obs.reshape(-1, 3)
    ids = torch.arange(3).repeat_interleave(4)
    jac = ilr_log_jacobian(flat).sum()
    for labels in (torch.tensor([-1, -1, -1]), torch.tensor([1, -1, 2])):
        stats = sequence_stats(flat, ids, labels.repeat_interleave(4), 3)
        ours = sequence_log_joint(stats, p, prior, HP) + jac
        per_seq = []
        for k in range(3):
            options = [labels[k].item()] if labels[k] >= 0 else range(3)
            per_seq.append(
                torch.logsumexp(
                    torch.stack(
                        [
                            prior[c].log()
                            + TwoLevelSequence(p["loc"][c], p["between"][c], p["within"], mask[k]).log_prob(obs[k])
                            for c in options
                        ]
                    ),
                    0,
                )
            )
        ref = sequence_prior_log_prob(p, HP) + sum(per_seq)
        torch.testing.assert_close(ours, ref, rtol=0, atol=1e-9)
        # Pyro: the same joint over the sampled Cholesky factors, i.e. plus their log Jacobians.
        trils = {k: torch.linalg.cholesky(p[k]) for k in ("between", "within", "between_mean")}
        data = {"loc": p["loc"], "between_pooling": p["between_pooling"]} | {f"{k}_tril": v for k, v in trils.items()}
        pyro.clear_param_store()
        loss = TraceEnum_ELBO(max_plate_nesting=1).loss(
            poutine.condition(sequence_model, data=data), lambda *a, **k: None, obs, mask, labels, prior, HP
        )
        d = 2
        powers = torch.arange(d, 0, -1, dtype=DT)
        log_jac = sum(
            (d * math.log(2) + (powers * t.diagonal(dim1=-2, dim2=-1).log()).sum(-1)).sum() for t in trils.values()
        )
        torch.testing.assert_close(torch.tensor(-loss, dtype=DT), ref + log_jac, rtol=0, atol=1e-8)


# -- kernels under pyro.infer.MCMC -------------------------------------------------------------


def test_confusion_kernel_runs_is_seeded_and_keeps_labels():
    obs, classes = confusion_data()
    labels = torch.where(torch.arange(30) % 2 == 0, classes, torch.tensor(-1))

    def run(seed):
        kernel = ConfusionMetropolis(num_chains=5, seed=seed)
        mcmc = MCMC(kernel, num_samples=40, warmup_steps=60, disable_progbar=True)
        mcmc.run(obs, labels)
        return kernel, mcmc.get_samples(group_by_chain=True)

    kernel, s = run(3)
    assert (
        s["beta"].shape == (1, 40, 5, 3, 3) and s["theta"].shape == (1, 40, 5, 3) and s["beta_loc"].shape == (1, 40, 5)
    )
    assert torch.equal(s["beta"].diagonal(dim1=-2, dim2=-1), torch.ones(1, 40, 5, 3, dtype=DT))
    assert set(kernel.diagnostics()["acceptance rate"]) == {"c", "conc", "hyper", "beta_scale"}
    assert set(kernel.logging()) == {"acc. c", "acc. conc", "acc. hyper", "acc. beta_scale"}
    probs = kernel.label_probs[0]
    torch.testing.assert_close(probs[labels >= 0], torch.nn.functional.one_hot(labels[labels >= 0], 3).to(DT))
    torch.testing.assert_close(probs.sum(-1), torch.ones(30, dtype=DT))
    again = run(3)[1]
    assert all(torch.equal(s[k], again[k]) for k in s)
    assert not torch.equal(s["theta"], run(4)[1]["theta"])


def test_sequence_kernel_runs_is_seeded_and_keeps_labels():
    obs, _ = sequences(9, 4)
    labels = torch.tensor([0, -1, 0, 1, -1, 1, 2, 2, -1])
    stats = sequence_stats(
        hbni_pyro.as_outputs(obs.reshape(-1, 3)), torch.arange(9).repeat_interleave(4), labels.repeat_interleave(4), 9
    )

    def run(seed):
        kernel = SequenceMetropolis(num_chains=4, seed=seed)
        mcmc = MCMC(kernel, num_samples=30, warmup_steps=30, disable_progbar=True)
        mcmc.run(stats)
        return kernel, mcmc.get_samples(group_by_chain=True)

    kernel, s = run(1)
    assert (
        s["loc"].shape == (1, 30, 4, 3, 2)
        and s["between"].shape == (1, 30, 4, 3, 2, 2)
        and s["within"].shape == (1, 30, 4, 2, 2)
    )
    assert (
        torch.linalg.cholesky_ex(s["between"]).info.eq(0).all()
        and torch.linalg.cholesky_ex(s["within"]).info.eq(0).all()
    )
    assert set(kernel.diagnostics()["acceptance rate"]) == {"pooling"}
    probs = kernel.label_probs[0]
    torch.testing.assert_close(probs[labels >= 0], torch.nn.functional.one_hot(labels[labels >= 0], 3).to(DT))
    again = run(1)[1]
    assert all(torch.equal(s[k], again[k]) for k in s)


@pytest.mark.parametrize("kernel", [ConfusionMetropolis, SequenceMetropolis])
def test_kernels_reject_bad_settings(kernel):
    with pytest.raises(ValueError, match="num_chains"):
        kernel(num_chains=0)
    with pytest.raises(TypeError, match="hyperprior"):
        kernel(hyperprior={"beta": 1.0})
    with pytest.raises(NotImplementedError, match="initial state"):
        kernel().initial_params = {}


# -- MH against NUTS ----------------------------------------------------------------------------


def test_confusion_mh_and_nuts_agree():
    """Posterior means of all 13 scalars within 4 Monte Carlo standard errors of a stored NUTS run
    (``nuts_references.py``): a family-wise false-alarm rate under 0.1 %."""
    ref = load_reference("confusion")
    mh = ref.problem.fit(num_chains=32, num_samples=1500, warmup_steps=1000, seed=1)
    assert set(mh.summary()) == set(ref.summary) and len(ref.summary) == 13 and ref.divergences == 0
    z = monte_carlo_z(mh.summary(), ref.summary)
    assert max(map(abs, z.values())) < 4, z


def test_sequence_mh_and_nuts_agree():
    """Posterior means of all 22 scalars within 4 Monte Carlo standard errors of a stored NUTS run, and the same
    class probabilities for the unlabelled sequences (within 0.15: NUTS recovers them from 100 draws).
    ``benchmarks/bench_noise_correctness.py`` repeats both comparisons with longer NUTS runs."""
    ref = load_reference("sequence")
    mh = ref.problem.fit(num_chains=32, num_samples=1500, warmup_steps=500, seed=1)
    assert set(mh.summary()) == set(ref.summary) and len(ref.summary) == 22
    z = monte_carlo_z(mh.summary(), ref.summary)
    assert max(map(abs, z.values())) < 4, z
    torch.testing.assert_close(mh.label_probs, ref.label_probs, rtol=0, atol=0.15)


@pytest.mark.parametrize("name", ["confusion", "sequence"])
def test_nuts_runs_on_the_model_and_recovers_the_labels(name):
    """A short live NUTS run (the stored references stand in for long ones): its sites are MH's, and labelled
    units have one-hot class probabilities."""
    problem = problems()[name]
    nuts = problem.fit(method="nuts", num_chains=1, num_samples=10, warmup_steps=10, seed=3)
    units = len(problem.obs)
    assert (
        nuts.info["method"] == "nuts"
        and nuts.samples.keys() == problem.fit(num_samples=2, warmup_steps=0).samples.keys()
    )
    assert nuts.label_probs.shape == (units, 3)
    torch.testing.assert_close(nuts.label_probs.sum(-1), torch.ones(units, dtype=DT))
    known = problem.labels >= 0
    assert torch.equal(nuts.label_probs[known], torch.nn.functional.one_hot(problem.labels[known], 3).to(DT))


# -- recovery -----------------------------------------------------------------------------------


def test_confusion_model_recovers_a_known_confusion_matrix():
    """From 600 labelled outputs per class, the posterior of every concentration covers the truth
    within 4 posterior standard deviations, and the implied mean-output (confusion) matrix
    ``E[o | c] = alpha_c / sum(alpha_c)`` is within 0.02 of the truth in every entry."""
    obs, classes = confusion_data(600, seed=8)
    post = hbni_pyro.fit(
        obs, classes, model="confusion", num_chains=8, num_samples=400, warmup_steps=400, seed=0, progress=False
    )
    draws = post.draws()
    alpha = concentrations(draws["theta"], draws["beta"])
    z = (alpha.mean(0) - ALPHA).abs() / alpha.std(0)
    assert z.max() < 4, z
    mean_output = (alpha / alpha.sum(-1, keepdim=True)).mean(0)
    torch.testing.assert_close(mean_output, ALPHA / ALPHA.sum(-1, keepdim=True), rtol=0, atol=0.02)
    # The confusions are real: class 0's pull towards class 1 is five times its pull towards class 2.
    assert (draws["beta"][:, 0, 1] > draws["beta"][:, 0, 2]).double().mean() > 0.99


def test_confusion_model_stays_with_the_paper_when_confusions_are_uniform():
    """Data from the paper's model (every beta_cj = 1): the shared level is near 0 and the spread small."""
    g = torch.Generator().manual_seed(9)
    classes = torch.arange(3).repeat_interleave(200)
    obs = hbni_pyro.sample_outputs(torch.tensor([1.0, 6.0, 20.0]), classes, g)
    post = hbni_pyro.fit(
        obs, classes, model="confusion", num_chains=8, num_samples=300, warmup_steps=300, seed=0, progress=False
    )
    s = post.summary()
    assert s["beta_loc"]["q5"] < 0 < s["beta_loc"]["q95"] and abs(s["beta_loc"]["mean"]) < 0.15
    assert s["beta_scale"]["mean"] < 0.2
    for m, t in enumerate((1.0, 6.0, 20.0)):
        assert s[f"theta[{m}]"]["q5"] < t < s[f"theta[{m}]"]["q95"]


def test_sequence_model_recovers_its_class_looks():
    obs, classes = sequences(60, 10, seed=10)
    flat = obs.reshape(-1, 3)
    post = hbni_pyro.fit(
        flat,
        classes.repeat_interleave(10),
        model="sequence",
        sequence_ids=torch.arange(60).repeat_interleave(10),
        num_chains=4,
        num_samples=300,
        warmup_steps=300,
        seed=0,
        progress=False,
    )
    draws = post.draws()
    z = (draws["loc"].mean(0) - LOC).abs() / draws["loc"].std(0)
    assert z.max() < 4, z
    z = (draws["within"].mean(0) - sequence_params()["within"]).abs() / draws["within"].std(0)
    assert z.max() < 4, z


# -- input errors --------------------------------------------------------------------------------


def test_fit_errors_name_the_argument():
    obs, _ = confusion_data(2)
    with pytest.raises(ValueError, match="model: expected one of"):
        hbni_pyro.fit(obs, model="gaussian", progress=False)
    with pytest.raises(ValueError, match="sequence_ids: the 'sequence' model needs"):
        hbni_pyro.fit(obs, model="sequence", progress=False)
    with pytest.raises(ValueError, match=r"sequence_ids: expected shape \(6,\)"):
        hbni_pyro.fit(obs, model="sequence", sequence_ids=[0, 1], progress=False)
    with pytest.raises(TypeError, match="sequence_ids: expected integer"):
        hbni_pyro.fit(obs, model="sequence", sequence_ids=torch.zeros(6), progress=False)
    with pytest.raises(ValueError, match="sequence_ids: entry 0 is negative"):
        hbni_pyro.fit(obs, model="sequence", sequence_ids=[-1, 0, 0, 1, 1, 1], progress=False)
    with pytest.raises(ValueError, match="labels: sequence 0 of dataset 0 mixes labels"):
        hbni_pyro.fit(obs, [0, 1, 1, 1, 2, 2], model="sequence", sequence_ids=[0, 0, 1, 1, 2, 2], progress=False)
    with pytest.raises(ValueError, match="num_chains: expected a multiple"):
        MCMC(ConfusionMetropolis(num_chains=3), num_samples=2, warmup_steps=0, disable_progbar=True).run(
            torch.stack([obs, obs])
        )
