"""Fitting the HBNI noise model: the paper's vectorised MH kernel, or Pyro NUTS as the reference.

``fit`` fits one dataset; ``fit_many`` fits many same-sized datasets in one vectorised MH
program (one block of chains per dataset), which is how a study that refits the model on
dozens of training sets stays fast.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import pyro
import torch
from pyro import poutine
from pyro.infer import MCMC, NUTS, infer_discrete
from torch import Tensor

from hbni_pyro.kernels import HBNIMetropolis
from hbni_pyro.model import HyperPrior, hbni_model
from hbni_pyro.posterior import HBNIPosterior, posterior_from_draws
from infra.threads import single_thread
from hbni_pyro.validation import DTYPE, as_class_prior, as_labels, as_outputs
from infra.checks import as_int

METHODS = ("mh", "nuts")
DEFAULT_CHAINS = {"mh": 16, "nuts": 2}
"""Chains per dataset when ``num_chains=None``: MH chains cost almost nothing extra (they share
one tensor program), NUTS chains run one after another on these CPUs."""


def fit(
    obs: Any,
    labels: Any = None,
    *,
    method: str = "mh",
    num_chains: int | None = None,
    num_samples: int = 1000,
    warmup_steps: int = 500,
    seed: int = 0,
    progress: bool = True,
    hyperprior: HyperPrior | None = None,
    class_prior: Any = None,
    jit: bool = True,
) -> HBNIPosterior:
    """Infer per-class noise ``theta`` (and ``kappa``, ``gamma``) from classifier outputs.

    Args:
        obs: ``(N, M)`` classifier outputs, rows on the simplex (exact zeros are floored).
        labels: ``(N,)`` true classes, ``-1`` where unknown; ``None`` means all unknown.
        method: ``"mh"`` (the paper's sampler, vectorised over chains) or ``"nuts"`` (Pyro NUTS
            with the classes enumerated out, labels recovered by ``infer_discrete``).
        num_chains: chains (``None`` = ``DEFAULT_CHAINS[method]``).
        num_samples, warmup_steps: post-warm-up draws per chain and warm-up iterations.
        seed: same seed, same draws.
        progress: show Pyro's progress bar.
        hyperprior: a :class:`HyperPrior` (``None`` = defaults).
        class_prior: ``(M,)`` prior ``p`` over classes (``None`` = uniform).
        jit: compile the NUTS potential with the PyTorch JIT (ignored by MH).

    Returns:
        An :class:`HBNIPosterior` with ``num_chains`` chains of ``num_samples`` draws.
    """
    x = as_outputs(obs, min_dim=2)
    if x.dim() != 2:
        raise ValueError(f"obs: expected shape (N, M), got {tuple(x.shape)}; use fit_many for a stack of datasets")
    y = None if labels is None else as_labels(labels, x.shape[0], x.shape[1])
    hp, p, chains, num_samples, warmup_steps, seed = _check_settings(
        method, num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, x.shape[1])
    if method == "mh":
        return _fit_mh(x.unsqueeze(0), None if y is None else y.unsqueeze(0), chains, num_samples, warmup_steps, seed, progress, hp, p)[0]
    return _fit_nuts(x, y, chains, num_samples, warmup_steps, seed, progress, hp, p, jit)


def fit_many(
    obs_sets: Any,
    labels: Any = None,
    *,
    num_chains: int | None = None,
    num_samples: int = 1000,
    warmup_steps: int = 500,
    seed: int = 0,
    progress: bool = True,
    hyperprior: HyperPrior | None = None,
    class_prior: Any = None,
) -> list[HBNIPosterior]:
    """Fit ``D`` independent datasets ``obs_sets (D, N, M)`` with MH in one vectorised run.

    ``labels`` is ``None`` or ``(D, N)`` with -1 for unknown. Returns ``D`` posteriors, each with
    ``num_chains`` chains; dataset ``d``'s chains see only dataset ``d``.
    """
    x = as_outputs(obs_sets, min_dim=3, name="obs_sets")
    if x.dim() != 3:
        raise ValueError(f"obs_sets: expected shape (D, N, M), got {tuple(x.shape)}")
    y = None
    if labels is not None:
        y = torch.stack([as_labels(row, x.shape[1], x.shape[2], name=f"labels[{d}]") for d, row in enumerate(torch.as_tensor(labels))])
        if y.shape[0] != x.shape[0]:
            raise ValueError(f"labels: expected {x.shape[0]} rows to match obs_sets, got {y.shape[0]}")
    hp, p, chains, num_samples, warmup_steps, seed = _check_settings(
        "mh", num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, x.shape[2])
    return _fit_mh(x, y, chains, num_samples, warmup_steps, seed, progress, hp, p)


def _check_settings(method, num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, num_classes):
    """Validated (hyperprior, class prior, chains, num_samples, warmup_steps, seed); numpy/torch ints accepted."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    chains = as_int("num_chains", DEFAULT_CHAINS[method] if num_chains is None else num_chains, minimum=1)
    sizes = as_int("num_samples", num_samples, minimum=1), as_int("warmup_steps", warmup_steps, minimum=0)
    hp = HyperPrior() if hyperprior is None else hyperprior
    if not isinstance(hp, HyperPrior):
        raise TypeError(f"hyperprior: expected a HyperPrior, got {type(hyperprior).__name__}")
    return hp, as_class_prior(class_prior, num_classes), chains, *sizes, as_int("seed", seed)


def _fit_mh(x, y, chains, num_samples, warmup_steps, seed, progress, hp, p) -> list[HBNIPosterior]:
    D, N, M = x.shape
    kernel = HBNIMetropolis(num_chains=D * chains, hyperprior=hp, class_prior=p, seed=seed)
    mcmc = MCMC(kernel, num_samples=num_samples, warmup_steps=warmup_steps, disable_progbar=not progress)
    start = time.perf_counter()
    with single_thread():
        mcmc.run(x.repeat_interleave(chains, 0), None if y is None else y.repeat_interleave(chains, 0))
    seconds = time.perf_counter() - start
    draws = {k: v[0].transpose(0, 1) for k, v in mcmc.get_samples(group_by_chain=True).items()}
    label_probs = kernel.label_probs.reshape(D, chains, N, M).mean(1)
    diag = kernel.diagnostics()
    info = {
        "method": "mh", "num_chains": chains, "num_samples": num_samples, "warmup_steps": warmup_steps,
        "seed": seed, "seconds": seconds, "datasets_in_run": D,
        "acceptance_rate": diag["acceptance rate"], "step_size_theta": diag["step size theta"],
    }
    return [
        posterior_from_draws(
            draws["theta"].reshape(D, chains, num_samples, M)[d],
            draws["kappa"].reshape(D, chains, num_samples)[d],
            draws["gamma"].reshape(D, chains, num_samples)[d],
            p, hp, label_probs=label_probs[d], info=info,
        )
        for d in range(D)
    ]


def _fit_nuts(x, y, chains, num_samples, warmup_steps, seed, progress, hp, p, jit) -> HBNIPosterior:
    pyro.set_rng_seed(seed)
    kernel = NUTS(hbni_model, max_plate_nesting=1, jit_compile=jit, ignore_jit_warnings=True)
    start = time.perf_counter()
    with warnings.catch_warnings(), single_thread():
        warnings.filterwarnings("ignore", message="num_chains=.*more than available_cpu")
        mcmc = MCMC(kernel, num_samples=num_samples, warmup_steps=warmup_steps, num_chains=chains, disable_progbar=not progress)
        mcmc.run(x, y, p, hp)
    seconds = time.perf_counter() - start
    draws = mcmc.get_samples(group_by_chain=True)
    divergences = mcmc.diagnostics().get("divergences", {})
    info = {
        "method": "nuts", "num_chains": chains, "num_samples": num_samples, "warmup_steps": warmup_steps,
        "seed": seed, "seconds": seconds, "jit": jit,
        "divergences": int(sum(len(v) for v in divergences.values())),
    }
    label_probs = recover_label_probs(draws, x, y, p, hp, seed=seed)
    return posterior_from_draws(draws["theta"], draws["kappa"], draws["gamma"], p, hp, label_probs=label_probs, info=info)


def recover_label_probs(
    draws: dict[str, Tensor], obs: Tensor, labels: Tensor | None, class_prior: Tensor, hyperprior: HyperPrior,
    max_draws: int = 100, seed: int = 0,
) -> Tensor:
    """Posterior class probabilities ``(N, M)`` of the training outputs, by ``infer_discrete``.

    For up to ``max_draws`` evenly spaced continuous draws, the classes are sampled from their
    exact conditional (``temperature=1``) and their frequencies returned; labelled rows are one-hot.
    """
    N, M = obs.shape
    flat = {k: v.reshape((-1,) + v.shape[2:]) for k, v in draws.items()}
    total = flat["theta"].shape[0]
    picks = torch.linspace(0, total - 1, min(max_draws, total)).round().long()
    known = torch.zeros(N, dtype=torch.bool) if labels is None else labels >= 0
    counts = torch.zeros(N, M, dtype=DTYPE)
    if known.any():
        counts[known] = torch.nn.functional.one_hot(labels[known], M).to(DTYPE) * len(picks)
    if (~known).any():
        pyro.set_rng_seed(seed)
        for i in picks.tolist():
            conditioned = poutine.condition(hbni_model, data={k: v[i] for k, v in flat.items()})
            sampler = infer_discrete(conditioned, first_available_dim=-2, temperature=1)
            trace = poutine.trace(sampler).get_trace(obs, labels, class_prior, hyperprior)
            counts[~known] += torch.nn.functional.one_hot(trace.nodes["c"]["value"], M).to(DTYPE)
    return counts / len(picks)
