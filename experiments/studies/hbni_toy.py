"""The paper's toy study: infer per-class noise from 15 unlabelled outputs of a 3-class classifier.

Writes ``posterior.safetensors`` (default hyperprior) and ``posterior_near_perfect.safetensors``,
``theta_posterior.png`` (theta posteriors, true values marked) and ``hyperparameters.png``
(kappa and gamma posteriors and the theta prior before and after inference under the
near-perfect hyperprior).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import torch
from hydra.utils import instantiate

import hbni_pyro
from experiments.runs.artifacts import save_artifact
from experiments.runs.outputs import save_figure
from experiments.schemas.noise_studies import HBNIToy
from hbni_pyro import gamma_log_prob, sample_outputs
from hbni_pyro.models.paper import prior_theta_log_density
from hbni_pyro.validation import DTYPE
from hbni_infra.streams import stream_seed, torch_stream


def run(settings: HBNIToy, run_dir: Path) -> dict:
    toy, seed = settings.toy, settings.seed
    theta_true = torch.tensor(toy.theta, dtype=DTYPE)
    classes = torch.arange(len(theta_true)).repeat_interleave(toy.per_class)
    obs = sample_outputs(theta_true, classes, torch_stream(seed, "outputs"))
    fit_kw = settings.hbni.fit.kwargs()
    posterior = hbni_pyro.fit(
        obs,
        **fit_kw,
        hyperprior=instantiate(settings.hbni.hyperprior),
        seed=stream_seed(seed, "fit"),
        progress=settings.progress,
    )
    confident = hbni_pyro.fit(
        obs,
        **fit_kw,
        hyperprior=instantiate(toy.near_perfect_hyperprior),
        seed=stream_seed(seed, "fit", "near perfect"),
        progress=settings.progress,
    )
    save_artifact(run_dir, "posterior", posterior)
    save_artifact(run_dir, "posterior_near_perfect", confident)
    save_figure(_theta_figure(posterior, theta_true), run_dir / "theta_posterior.png")
    save_figure(_hyper_figure(confident), run_dir / "hyperparameters.png")
    summary = posterior.summary()
    inside = [
        summary[f"theta[{m}]"]["q5"] <= float(t) <= summary[f"theta[{m}]"]["q95"] for m, t in enumerate(theta_true)
    ]
    return {
        "theta_true": theta_true,
        "outputs": len(classes),
        "summary": summary,
        "true_theta_in_90pct_interval": inside,
        "label_accuracy": float((posterior.label_probs.argmax(-1) == classes).double().mean()),
        "near_perfect_prior": {"summary": confident.summary()},
        "fit": posterior.info,
    }


def _theta_figure(posterior: hbni_pyro.HBNIPosterior, theta_true: torch.Tensor) -> plt.Figure:
    draws = posterior.theta_draws()
    fig, axes = plt.subplots(1, posterior.num_classes, figsize=(4 * posterior.num_classes, 3.2), sharey=False)
    for m, ax in enumerate(axes):
        x = draws[:, m].log10()
        ax.hist(x.numpy(), bins=60, density=True, color="tab:blue", alpha=0.7)
        ax.axvline(float(theta_true[m].log10()), color="k", ls="--", label=f"true θ = {float(theta_true[m]):g}")
        ax.set_xlabel(f"log10 θ{m + 1}")
        ax.set_title(f"class {m + 1}")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("posterior density")
    fig.suptitle(
        y=1.04,
        t=f"θ posteriors from {posterior.label_probs.shape[0]} unlabelled outputs (MH, {posterior.num_chains} chains)",
    )
    return fig


def _hyper_figure(posterior: hbni_pyro.HBNIPosterior) -> plt.Figure:
    hp = posterior.hyperprior
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.4))
    for ax, name, (shape, scale) in zip(axes[:2], ("kappa", "gamma"), ((hp.beta, hp.eta), (hp.nu, hp.omega))):
        x = posterior.samples[name].reshape(-1)
        ax.hist(x.numpy(), bins=60, density=True, alpha=0.7, label="posterior")
        grid = torch.linspace(float(x.min()) * 0.5, float(x.max()) * 1.5, 300, dtype=DTYPE)
        ax.plot(grid, gamma_log_prob(grid, shape, scale).exp(), "k--", label=f"prior Ga({shape:g}, {scale:g})")
        ax.set_xlabel(name)
        ax.legend(fontsize=8)
    grid = torch.logspace(-1, 3, 400, dtype=DTYPE)
    before = prior_theta_log_density(grid, hp).exp()
    k = posterior.samples["kappa"].reshape(-1)
    g = posterior.samples["gamma"].reshape(-1)
    after = torch.logsumexp(gamma_log_prob(grid.unsqueeze(-1), k, g), -1).exp() / k.numel()
    ax = axes[2]
    ax.plot(grid, grid * before, label="before inference")
    ax.plot(grid, grid * after, label="after inference")
    ax.set_xscale("log")
    ax.set_xlabel("θ")
    ax.set_ylabel("density of log θ")
    ax.set_title("θ prior implied by the hyperparameters")
    ax.legend(fontsize=8)
    fig.suptitle(y=1.04, t="Near-perfect-classifier hyperprior (prior median θ ≈ 100) updated by 15 noisy outputs")
    return fig
