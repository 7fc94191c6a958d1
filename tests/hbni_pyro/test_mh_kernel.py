"""The hand-written MH kernel: Pyro driver integration, determinism and a Geweke joint-distribution test."""

import math

import pytest
import torch
from pyro.infer import MCMC

from hbni_pyro import HBNIMetropolis, HyperPrior, as_outputs, sample_outputs
from hbni_pyro.distributions import gamma_variates
from hbni_pyro.mcmc import MHState, alias_draw, alias_tables, frame_data, update_classes
from hbni_pyro.mcmc import update_hyper
from hbni_pyro.models.paper.steps import update_theta


def _toy_obs(seed=0):
    g = torch.Generator().manual_seed(seed)
    return sample_outputs(torch.tensor([1.0, 6.0, 20.0]), torch.arange(3).repeat_interleave(5), g)


def test_kernel_runs_under_pyro_mcmc_with_chain_batch_and_diagnostics():
    obs = as_outputs(_toy_obs())
    kernel = HBNIMetropolis(num_chains=7, seed=3)
    mcmc = MCMC(kernel, num_samples=50, warmup_steps=50, disable_progbar=True)
    mcmc.run(obs)
    s = mcmc.get_samples(group_by_chain=True)
    assert s["theta"].shape == (1, 50, 7, 3) and s["kappa"].shape == (1, 50, 7)
    assert (s["theta"] > 0).all() and (s["gamma"] > 0).all()
    diag = kernel.diagnostics()
    assert diag["divergences"] == [] and set(diag["acceptance rate"]) == {"c", "theta", "hyper"}
    assert "divergences" in mcmc.diagnostics()
    assert set(kernel.logging()) == {"acc. c", "acc. theta", "acc. hyper"}
    # Robbins-Monro warm-up drives the 1-D theta moves towards acceptance 0.44.
    assert 0.25 < diag["acceptance rate"]["theta"] < 0.65
    torch.testing.assert_close(kernel.label_probs.sum(-1), torch.ones(1, 15, dtype=torch.float64))


def test_kernel_is_deterministic_given_seed():
    obs = as_outputs(_toy_obs())

    def run(seed):
        mcmc = MCMC(HBNIMetropolis(num_chains=4, seed=seed), num_samples=30, warmup_steps=20, disable_progbar=True)
        mcmc.run(obs)
        return mcmc.get_samples()["theta"]

    assert torch.equal(run(5), run(5))
    assert not torch.equal(run(5), run(6))


@pytest.mark.parametrize("seed", [0, 4])
def test_unlabelled_chains_agree(seed):
    """5000 unlabelled 10-class outputs, 16 chains: with classes initialised from draws of the proposal, one chain
    of these seeds settled at near-uniform classes and theta near 0 (split R-hat of theta 13); every chain now
    starts its classes at each output's largest entry and all of them find the one posterior mode."""
    import hbni_pyro
    from hbni_pyro import HBNIPosterior

    g = torch.Generator().manual_seed(0)
    theta = torch.linspace(1.0, 20.0, 10, dtype=torch.float64)
    obs = sample_outputs(theta, torch.arange(10).repeat_interleave(500), g)
    post: HBNIPosterior = hbni_pyro.fit(
        obs, num_chains=16, num_samples=300, warmup_steps=300, seed=seed, progress=False
    )
    chain_means = post.draws()["theta"].mean(1)  # (chains, M)
    assert (chain_means.min(0).values > 0.8 * chain_means.max(0).values).all()
    assert max(row["r_hat"] for name, row in post.summary().items() if name.startswith("theta")) < 1.2


def test_labelled_outputs_keep_their_class():
    obs = as_outputs(_toy_obs())
    labels = torch.tensor([0] * 5 + [-1] * 10)
    kernel = HBNIMetropolis(num_chains=3, seed=0)
    MCMC(kernel, num_samples=40, warmup_steps=10, disable_progbar=True).run(obs, labels)
    torch.testing.assert_close(kernel.label_probs[:, :5, 0], torch.ones(1, 5, dtype=torch.float64))


@pytest.mark.parametrize("num_classes", [2, 3, 10])
def test_alias_tables_reproduce_their_weights_exactly(num_classes):
    """Column ``k`` is drawn with ``(prob[k] + sum_{j: alias[j] = k} (1 - prob[j])) / M``: that closed
    form must give back the weights (random rows, near-zero entries, ties, one-hot and uniform rows)."""
    g = torch.Generator().manual_seed(num_classes)
    w = torch.rand(4, 50, num_classes, generator=g, dtype=torch.float64) ** 4
    w[0, 0] = 1.0
    w[0, 1] = 0.0
    w[0, 1, 0] = 1.0
    w[0, 2, :] = torch.arange(num_classes) % 2 + 1e-9
    w = w / w.sum(-1, keepdim=True)
    prob, alias = alias_tables(w)
    assert ((prob >= 0) & (prob <= 1)).all() and ((alias >= 0) & (alias < num_classes)).all()
    implied = (prob + torch.zeros_like(prob).scatter_add_(-1, alias, 1 - prob)) / num_classes
    torch.testing.assert_close(implied, w, rtol=0, atol=1e-12)


def test_alias_draw_frequencies_match_the_weights():
    """400 000 draws from one row: each class frequency within 4.5 binomial standard errors."""
    g = torch.Generator().manual_seed(1)
    w = torch.tensor([0.5, 0.02, 0.3, 0.0, 0.18], dtype=torch.float64)
    n = 400_000
    draws = alias_draw(*alias_tables(w), torch.rand(n, generator=g, dtype=torch.float64))
    freq = torch.bincount(draws, minlength=5).double() / n
    se = (w * (1 - w) / n).sqrt()
    assert ((freq - w).abs() <= 4.5 * se + 1e-12).all(), (freq, w)


@pytest.mark.parametrize("confusion", [False, True])
def test_class_move_transition_probabilities(confusion):
    """One class move from a fixed class: the frequency of each next class over 200 000 chains
    matches the exact MH transition ``(1 - stay) w_k min(1, pi_k w_c / (pi_c w_k))`` (stay
    otherwise), with ``pi`` from ``torch.distributions.Dirichlet`` as an independent density, within
    4.5 binomial standard errors."""
    g = torch.Generator().manual_seed(7)
    M, C, stay = 4, 200_000, 0.3
    o = torch.tensor([[0.15, 0.5, 0.05, 0.3]], dtype=torch.float64)
    theta = torch.tensor([2.0, 5.0, 0.7, 9.0], dtype=torch.float64)
    prior = torch.tensor([0.1, 0.4, 0.2, 0.3], dtype=torch.float64)
    beta = 0.5 + torch.rand(M, M, generator=g, dtype=torch.float64) if confusion else None
    alpha = torch.ones(M, M, dtype=torch.float64) if beta is None else beta.clone()
    alpha.fill_diagonal_(1.0)
    alpha = alpha + torch.diag(theta)
    log_pi = torch.distributions.Dirichlet(alpha).log_prob(o) + prior.log()
    w = 0.5 * o[0] + 0.5 / M
    cur = 1
    accept = (log_pi - log_pi[cur] + w[cur].log() - w.log()).exp().clamp_max(1)
    exact = (1 - stay) * w * accept
    exact[cur] = 1 - exact.sum() + exact[cur]
    state = MHState(
        torch.full((C, 1), cur),
        theta.log().expand(C, M),
        torch.zeros(C, dtype=torch.float64),
        torch.zeros(C, dtype=torch.float64),
    )
    data = frame_data(o, torch.tensor([-1]), prior.log())
    new_c, accepted = update_classes(state, data, stay, g, beta=None if beta is None else beta.expand(C, M, M))
    freq = torch.bincount(new_c.reshape(-1), minlength=M).double() / C
    se = (exact * (1 - exact) / C).sqrt()
    assert ((freq - exact).abs() <= 4.5 * se).all(), (freq, exact)
    assert new_c is state.c and int(accepted) == int((new_c != cur).sum())


@pytest.mark.parametrize("kwargs, match", [({"num_chains": 0}, "num_chains"), ({"stay_prob": 1.0}, "stay_prob")])
def test_kernel_rejects_bad_settings(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HBNIMetropolis(**kwargs)


def test_geweke_joint_distribution():
    """Geweke's successive-conditional simulator: alternate one MH iteration on (c, theta, kappa,
    gamma) given the outputs with a fresh draw of the outputs given (c, theta). If every move
    leaves the posterior invariant, the joint chain keeps the prior as its marginal, so after
    T iterations the C independent chains are prior draws. Each statistic's mean is compared
    with its exact prior mean (or a large independent prior sample) at 4.5 standard errors
    of C independent draws (family-wise false-alarm rate about 1e-4 over the 8 statistics).
    """
    gen = torch.Generator().manual_seed(11)
    hp = HyperPrior(beta=4.0, eta=0.5, nu=4.0, omega=2.5)
    C, N, M, T = 4000, 6, 3, 60
    prior = torch.tensor([0.5, 0.3, 0.2], dtype=torch.float64)

    def prior_draw(n):
        kappa = gamma_variates(torch.full((n,), hp.beta), hp.eta, gen)
        gamma = gamma_variates(torch.full((n,), hp.nu), hp.omega, gen)
        theta = gamma_variates(kappa.unsqueeze(-1).expand(n, M), gamma.unsqueeze(-1), gen)
        c = torch.multinomial(prior.expand(n, M), N, replacement=True, generator=gen)
        return c, theta, kappa, gamma

    def outputs(c, theta):
        o = sample_outputs(theta.unsqueeze(-2).expand(c.shape + (M,)), c, gen)
        return o.clamp_min(1e-300)

    def stats(c, log_theta, log_kappa, log_gamma):
        one_hot = torch.nn.functional.one_hot(c, M).double().mean(-2)
        return torch.stack(
            [
                log_theta[:, 0],
                log_theta[:, 2],
                log_theta.var(-1),
                log_kappa,
                log_gamma,
                one_hot[:, 0],
                one_hot[:, 2],
                log_theta.exp().log1p().mean(-1),
            ],
            -1,
        )

    c, theta, kappa, gamma = prior_draw(C)
    state = MHState(c, theta.log(), kappa.log(), gamma.log())
    step = torch.full((C, M), 0.8, dtype=torch.float64)
    chol = torch.diag(torch.tensor([0.5, 0.5], dtype=torch.float64)).expand(C, 2, 2)
    labels = torch.full((C, N), -1)
    for _ in range(T):
        o = outputs(state.c, state.log_theta.exp())
        data = frame_data(o, labels, prior.log())
        state = state._replace(c=update_classes(state, data, 0.5, gen)[0])
        state = state._replace(log_theta=update_theta(state, data, step, gen)[0])
        lk, lg, _ = update_hyper(state, hp, chol, gen)
        state = state._replace(log_kappa=lk, log_gamma=lg)
    joint = stats(*state)
    c0, th0, k0, g0 = prior_draw(200_000)
    ref = stats(c0, th0.log(), k0.log(), g0.log())
    se = (joint.var(0) / C + ref.var(0) / ref.shape[0]).sqrt()
    z = (joint.mean(0) - ref.mean(0)) / se
    assert z.abs().max() < 4.5, f"Geweke z-scores {z.tolist()}"


def test_geweke_detects_a_missing_hastings_correction():
    """The same check fails when the class move drops its Hastings term (the test has power)."""
    gen = torch.Generator().manual_seed(12)
    M, N, C = 3, 6, 4000
    theta = torch.tensor([[1.0, 6.0, 20.0]], dtype=torch.float64).expand(C, M)
    prior = torch.full((M,), 1 / M, dtype=torch.float64)
    c = torch.multinomial(prior.expand(C, M), N, replacement=True, generator=gen)
    state = MHState(c, theta.log(), torch.zeros(C, dtype=torch.float64), torch.zeros(C, dtype=torch.float64))
    labels = torch.full((C, N), -1)

    def frac_class0(correct):
        s = state._replace(c=state.c.clone())  # the class move rewrites the classes in place
        for _ in range(30):
            o = sample_outputs(theta.unsqueeze(-2).expand(C, N, M), s.c, gen)
            data = frame_data(o, labels, prior.log())
            if not correct:
                data = data._replace(log_proposal=torch.zeros_like(data.log_proposal))
            s = s._replace(c=update_classes(s, data, 0.5, gen)[0])
        return torch.nn.functional.one_hot(s.c, M).double().mean((0, 1))

    expected = 1 / M
    se = math.sqrt(expected * (1 - expected) / (C * N)) * math.sqrt(N)  # conservative: outputs in a chain share theta
    assert abs(frac_class0(True)[0] - expected) < 4.5 * se
    assert abs(frac_class0(False)[0] - expected) > 4.5 * se
