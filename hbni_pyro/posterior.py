"""``HBNIPosterior``: posterior draws of the HBNI noise model, their summary, storage and predictive."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from pyro.ops.stats import effective_sample_size, split_gelman_rubin
from torch import Tensor

from hbni_pyro.generative import sample_outputs
from hbni_pyro.model import HyperPrior
from infra.tensorfile import load_tensors, save_tensors
from hbni_pyro.validation import DTYPE

_KIND = "hbni_pyro.HBNIPosterior"
_SITES = ("theta", "kappa", "gamma")


@dataclass
class HBNIPosterior:
    """Posterior draws by chain.

    Attributes:
        samples: ``{"theta": (chains, draws, M), "kappa": (chains, draws), "gamma": (chains, draws)}``.
        class_prior: ``(M,)`` class prior ``p`` used in the fit.
        hyperprior: the :class:`HyperPrior` used in the fit.
        label_probs: ``(N, M)`` posterior probability of each training output's class, or ``None``.
        info: JSON-serialisable fit metadata (method, settings, sampler diagnostics).
    """

    samples: dict[str, Tensor]
    class_prior: Tensor
    hyperprior: HyperPrior = field(default_factory=HyperPrior)
    label_probs: Tensor | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [k for k in _SITES if k not in self.samples]
        if missing:
            raise ValueError(f"samples: missing sites {missing}, expected {list(_SITES)}")
        theta = self.samples["theta"]
        if theta.dim() != 3:
            raise ValueError(f"samples['theta']: expected shape (chains, draws, M), got {tuple(theta.shape)}")
        for k in ("kappa", "gamma"):
            if self.samples[k].shape != theta.shape[:2]:
                raise ValueError(f"samples[{k!r}]: expected shape {tuple(theta.shape[:2])}, got {tuple(self.samples[k].shape)}")

    @property
    def num_classes(self) -> int:
        return self.samples["theta"].shape[-1]

    @property
    def num_chains(self) -> int:
        return self.samples["theta"].shape[0]

    @property
    def num_draws(self) -> int:
        return self.samples["theta"].shape[1]

    def theta_draws(self) -> Tensor:
        """All draws of theta pooled over chains, ``(chains * draws, M)``."""
        return self.samples["theta"].reshape(-1, self.num_classes)

    def theta_point(self, estimate: str = "mean") -> Tensor:
        """Plug-in point estimate of theta ``(M,)``: ``"mean"`` or ``"median"``."""
        draws = self.theta_draws()
        if estimate == "mean":
            return draws.mean(0)
        if estimate == "median":
            return draws.median(0).values
        raise ValueError(f"estimate: expected 'mean' or 'median', got {estimate!r}")

    def summary(self, prob: float = 0.9) -> dict[str, dict[str, float]]:
        """Per scalar parameter (``theta[0]``, ..., ``kappa``, ``gamma``): mean, sd, 5 % and 95 %
        quantiles (for ``prob=0.9``), ESS and split R-hat, computed with ``pyro.ops.stats``."""
        lo, hi = (1 - prob) / 2, (1 + prob) / 2
        out: dict[str, dict[str, float]] = {}
        for name, x in self._scalar_sites().items():
            flat = x.reshape(-1)
            q = torch.quantile(flat, torch.tensor([lo, hi], dtype=flat.dtype))
            rhat = split_gelman_rubin(x, chain_dim=0, sample_dim=1) if self.num_draws >= 4 else torch.tensor(float("nan"))
            out[name] = {
                "mean": float(flat.mean()),
                "sd": float(flat.std()),
                f"q{lo * 100:g}": float(q[0]),
                f"q{hi * 100:g}": float(q[1]),
                "ess": float(effective_sample_size(x, chain_dim=0, sample_dim=1)),
                "r_hat": float(rhat),
            }
        return out

    def _scalar_sites(self) -> dict[str, Tensor]:
        sites = {f"theta[{m}]": self.samples["theta"][..., m] for m in range(self.num_classes)}
        sites["kappa"] = self.samples["kappa"]
        sites["gamma"] = self.samples["gamma"]
        return sites

    def sample_outputs(self, true_class: int, n: int, seed: int = 0) -> Tensor:
        """Posterior-predictive classifier outputs ``(n, M)`` for class ``true_class``.

        Each output uses its own theta drawn uniformly from the pooled posterior draws.
        """
        if not (isinstance(true_class, int) and 0 <= true_class < self.num_classes):
            raise ValueError(f"true_class: expected an int in [0, {self.num_classes}), got {true_class!r}")
        if not (isinstance(n, int) and n >= 1):
            raise ValueError(f"n: expected a positive int, got {n!r}")
        g = torch.Generator().manual_seed(seed)
        draws = self.theta_draws()
        idx = torch.randint(draws.shape[0], (n,), generator=g)
        return sample_outputs(draws[idx], torch.full((n,), true_class, dtype=torch.long), g)

    def save(self, path: str | os.PathLike) -> Path:
        """Write draws and metadata to one safetensors file, atomically."""
        tensors = dict(self.samples)
        tensors["class_prior"] = self.class_prior
        if self.label_probs is not None:
            tensors["label_probs"] = self.label_probs
        meta = {"version": 1, "hyperprior": self.hyperprior.as_dict(), "info": self.info}
        return save_tensors(path, _KIND, tensors, meta)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "HBNIPosterior":
        """Read a file written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, meta = load_tensors(path, _KIND)
        try:
            return cls(
                samples={k: tensors[k] for k in _SITES},
                class_prior=tensors["class_prior"],
                hyperprior=HyperPrior(**meta["hyperprior"]),
                label_probs=tensors.get("label_probs"),
                info=meta.get("info", {}),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{path}: incomplete saved {_KIND} (missing {exc})") from None

    def to_arviz(self) -> Any:
        """An ``arviz.InferenceData`` with the draws (needs the optional ``arviz`` package)."""
        try:
            import arviz
        except ImportError as exc:
            raise ImportError("to_arviz() needs arviz: pip install arviz") from exc
        return arviz.from_dict(
            posterior={k: v.numpy() for k, v in self.samples.items()},
            dims={"theta": ["class"]},
            coords={"class": list(range(self.num_classes))},
        )

    def __repr__(self) -> str:
        means = ", ".join(f"{float(v):.3g}" for v in self.theta_point())
        return (
            f"HBNIPosterior(M={self.num_classes}, chains={self.num_chains}, draws={self.num_draws}, "
            f"theta mean=[{means}], method={self.info.get('method')!r})"
        )


def posterior_from_draws(
    theta: Tensor, kappa: Tensor, gamma: Tensor, class_prior: Tensor, hyperprior: HyperPrior, **kwargs: Any
) -> HBNIPosterior:
    """Build a posterior from ``(chains, draws, ...)`` tensors, cast to float64."""
    samples = {"theta": theta.to(DTYPE), "kappa": kappa.to(DTYPE), "gamma": gamma.to(DTYPE)}
    return HBNIPosterior(samples, class_prior.to(DTYPE), hyperprior, **kwargs)
