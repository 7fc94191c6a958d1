"""``HBNIPosterior``: posterior draws of an HBNI noise model, their summary, storage and predictive."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from pyro.ops.stats import effective_sample_size, split_gelman_rubin
from torch import Tensor

from hbni_pyro.density import concentrations
from hbni_pyro.generative import sample_dirichlet, sample_outputs, sample_sequences
from hbni_pyro.model import HyperPrior
from hbni_pyro.validation import DTYPE
from hbni_pyro.variants import MODELS, check_model, site_shapes
from infra.checks import as_names
from infra.tensorfile import load_tensors, save_tensors

_KIND = "hbni_pyro.HBNIPosterior"
_VERSION = 2  # format version of saved posteriors


def _num_classes(model: str, samples: dict[str, Tensor]) -> int:
    key = "loc" if model == "sequence" else "theta"
    if key not in samples:
        raise ValueError(f"samples: missing sites [{key!r}], expected {list(site_shapes(model, 2))} for model {model!r}")
    x = samples[key]
    return x.shape[-2] if model == "sequence" and x.dim() >= 2 else x.shape[-1]


@dataclass
class HBNIPosterior:
    """Posterior draws by chain.

    Attributes:
        samples: site -> ``(chains, draws, *site shape)``; the sites of each model are in
            :func:`hbni_pyro.variants.site_shapes` (paper: ``theta (M,)``, ``kappa``, ``gamma``).
        class_prior: ``(M,)`` class prior ``p`` used in the fit.
        hyperprior: the :class:`HyperPrior` used in the fit.
        label_probs: ``(N, M)`` posterior probability of each training output's class, or ``None``.
        info: JSON-serialisable fit metadata (method, settings, sampler diagnostics).
        model: the noise model, one of :data:`hbni_pyro.variants.MODELS` (default ``"paper"``).
        class_names: the name of each class, in the order of the outputs' columns (``None``: unnamed); filters,
            tables and streams built on the posterior check their names against it.
    """

    samples: dict[str, Tensor]
    class_prior: Tensor
    hyperprior: HyperPrior = field(default_factory=HyperPrior)
    label_probs: Tensor | None = None
    info: dict[str, Any] = field(default_factory=dict)
    model: str = "paper"
    class_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        check_model(self.model)
        self.class_names = as_names("class_names", self.class_names, _num_classes(self.model, self.samples))
        shapes = site_shapes(self.model, _num_classes(self.model, self.samples))
        missing = [k for k in shapes if k not in self.samples]
        if missing:
            raise ValueError(f"samples: missing sites {missing}, expected {list(shapes)} for model {self.model!r}")
        first = next(iter(shapes))
        lead = self.samples[first].shape[:2]
        if self.samples[first].dim() != 2 + len(shapes[first]):
            raise ValueError(f"samples[{first!r}]: expected shape (chains, draws, *{shapes[first]}), got {tuple(self.samples[first].shape)}")
        for k, shape in shapes.items():
            if tuple(self.samples[k].shape) != tuple(lead) + shape:
                raise ValueError(f"samples[{k!r}]: expected shape {tuple(lead) + shape}, got {tuple(self.samples[k].shape)}")

    @property
    def num_classes(self) -> int:
        return _num_classes(self.model, self.samples)

    @property
    def num_chains(self) -> int:
        return next(iter(self.samples.values())).shape[0]

    @property
    def num_draws(self) -> int:
        return next(iter(self.samples.values())).shape[1]

    def draws(self) -> dict[str, Tensor]:
        """Every site's draws pooled over chains, ``(chains * draws, *site shape)``."""
        return {k: v.reshape((-1,) + v.shape[2:]) for k, v in self.samples.items()}

    def theta_draws(self) -> Tensor:
        """All draws of theta pooled over chains, ``(chains * draws, M)`` (frame-level models only)."""
        if "theta" not in self.samples:
            raise ValueError(f"theta_draws: the {self.model!r} model has no theta; use draws()")
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
        """Per scalar parameter (``theta[0]``, ..., ``kappa``, ``gamma``; matrices entry by entry, the
        off-diagonal of ``beta`` and the upper triangle of covariances): mean, sd, the central
        ``prob`` interval's quantiles (``q5``, ``q95`` for 0.9), ESS and split R-hat (``pyro.ops.stats``)."""
        lo, hi = (1 - prob) / 2, (1 + prob) / 2
        out: dict[str, dict[str, float]] = {}
        for name, x in self.scalar_sites().items():
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

    def scalar_sites(self) -> dict[str, Tensor]:
        """Every free scalar of the posterior as ``(chains, draws)``, named ``site[i, j]``."""
        sites: dict[str, Tensor] = {}
        for name, x in self.samples.items():
            shape = x.shape[2:]
            for index in torch.cartesian_prod(*(torch.arange(n) for n in shape)).reshape(-1, len(shape)).tolist() if shape else [[]]:
                if not _free_entry(name, index):
                    continue
                label = f"{name}[{', '.join(map(str, index))}]" if index else name
                sites[label] = x[(slice(None), slice(None), *index)]
        return sites

    def sample_outputs(self, true_class: int, n: int, seed: int = 0) -> Tensor:
        """Posterior-predictive classifier outputs ``(n, M)`` for class ``true_class``, each from its own
        posterior draw (and, under the sequence model, its own sequence)."""
        self._check_class(true_class)
        if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
            raise ValueError(f"n: expected a positive int, got {n!r}")
        return self.sample_streams(true_class, n, 1, seed)[:, 0]

    def sample_streams(
        self, true_class: int, num_streams: int, num_frames: int, seed: int = 0, *, generator: torch.Generator | None = None
    ) -> Tensor:
        """Posterior-predictive output streams ``(num_streams, num_frames, M)`` of new class-``true_class`` objects.

        Each stream takes one posterior draw; its frames are then i.i.d. given it (frame-level
        models) or share one new look (the sequence model). ``generator``, when given, is used (and
        advanced) instead of a new one seeded with ``seed``.
        """
        self._check_class(true_class)
        for name, v in (("num_streams", num_streams), ("num_frames", num_frames)):
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"{name}: expected a positive int, got {v!r}")
        if generator is not None and not isinstance(generator, torch.Generator):
            raise TypeError(f"generator: expected a torch.Generator or None, got {type(generator).__name__}")
        g = generator if generator is not None else torch.Generator().manual_seed(seed)
        draws = self.draws()
        first = next(iter(draws.values()))
        idx = torch.randint(first.shape[0], (num_streams,), generator=g)
        classes = torch.full((num_streams, num_frames), true_class, dtype=torch.long)
        if self.model == "paper":
            return sample_outputs(draws["theta"][idx].unsqueeze(1), classes, g)
        if self.model == "confusion":
            alpha = concentrations(draws["theta"][idx], draws["beta"][idx])[:, true_class]
            return sample_dirichlet(alpha.unsqueeze(1).expand(num_streams, num_frames, -1), g)
        return sample_sequences(draws["loc"][idx, true_class], draws["between"][idx, true_class],
                                draws["within"][idx].unsqueeze(1), torch.arange(num_streams), num_frames, g)

    def _check_class(self, true_class: int) -> None:
        if not (isinstance(true_class, int) and not isinstance(true_class, bool) and 0 <= true_class < self.num_classes):
            raise ValueError(f"true_class: expected an int in [0, {self.num_classes}), got {true_class!r}")

    def save(self, path: str | os.PathLike) -> Path:
        """Write draws and metadata to one safetensors file, atomically."""
        tensors = {k: v.clone() for k, v in self.samples.items()}  # one buffer each, even if two sites share memory
        tensors["class_prior"] = self.class_prior
        if self.label_probs is not None:
            tensors["label_probs"] = self.label_probs
        meta = {"model": self.model, "hyperprior": self.hyperprior.as_dict(), "info": self.info,
                "class_names": None if self.class_names is None else list(self.class_names)}
        return save_tensors(path, _KIND, tensors, meta, version=_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "HBNIPosterior":
        """Read a file written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, meta = load_tensors(path, _KIND, version=_VERSION)
        model = meta.get("model", "paper")
        if model not in MODELS:
            raise ValueError(f"{path}: unknown noise model {model!r} in saved {_KIND}, expected one of {MODELS}")
        try:
            num_classes = _num_classes(model, tensors)
            return cls(
                samples={k: tensors[k] for k in site_shapes(model, num_classes)},
                class_prior=tensors["class_prior"],
                hyperprior=HyperPrior(**meta["hyperprior"]),
                label_probs=tensors.get("label_probs"),
                info=meta.get("info", {}),
                model=model,
                class_names=meta.get("class_names"),
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
            dims={"theta": ["class"], "beta": ["class", "class_to"], "loc": ["class", "coord"]},
            coords={"class": list(range(self.num_classes)), "class_to": list(range(self.num_classes)),
                    "coord": list(range(self.num_classes - 1))},
        )

    def __repr__(self) -> str:
        head = f"HBNIPosterior(model={self.model!r}, M={self.num_classes}, chains={self.num_chains}, draws={self.num_draws}"
        if "theta" in self.samples:
            head += ", theta mean=[" + ", ".join(f"{float(v):.3g}" for v in self.theta_point()) + "]"
        return head + f", method={self.info.get('method')!r})"


def _free_entry(name: str, index: list[int]) -> bool:
    """Whether entry ``index`` of site ``name`` is a free parameter (not ``beta``'s fixed diagonal,
    not a covariance's mirrored lower triangle)."""
    if name == "beta":
        return index[0] != index[1]
    if name in ("between", "between_mean", "within"):
        return index[-2] <= index[-1]
    return True


def posterior_from_samples(
    samples: dict[str, Tensor], class_prior: Tensor, hyperprior: HyperPrior, model: str = "paper", **kwargs: Any
) -> HBNIPosterior:
    """Build a posterior from ``(chains, draws, ...)`` tensors, cast to float64."""
    samples = {k: v.to(DTYPE) for k, v in samples.items()}
    return HBNIPosterior(samples, class_prior.to(DTYPE), hyperprior, model=model, **kwargs)
