"""``HBNIPosterior``: posterior draws of an HBNI noise model, their summary, storage and predictive."""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from pyro.ops.stats import split_gelman_rubin
from pyro.ops.tensor_utils import next_fast_len
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.models import NoiseModel, model_names, noise_model
from hbni_pyro.validation import DTYPE, as_class_prior, has_values
from hbni_infra.checks import as_device, as_float, as_generator, as_int, as_names
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.optional import require
from hbni_infra.streams import torch_generator

_KIND = "hbni_pyro.HBNIPosterior"
_VERSION = 2  # format version of saved posteriors


@dataclass
class HBNIPosterior:
    """Posterior draws by chain.

    Attributes:
        samples: site -> ``(chains, draws, *site shape)``; the sites of each model are its spec's
            ``site_shapes`` (:mod:`hbni_pyro.models`; paper: ``theta (M,)``, ``kappa``, ``gamma``).
        class_prior: ``(M,)`` class prior ``p`` used in the fit.
        hyperprior: the :class:`HyperPrior` used in the fit.
        label_probs: ``(N, M)`` posterior probability of each training output's class, or ``None``.
        info: JSON-serialisable fit metadata (method, settings, sampler diagnostics).
        model: the noise model's name, a key of :data:`hbni_pyro.models.NOISE_MODELS` (default ``"paper"``).
        class_names: the name of each class, in the order of the outputs' columns (``None``: unnamed); filters,
            tables and streams built on the posterior check their names against it.
        frame_correlation: the lag-1 correlation in ``(-1, 1)`` of a stream's frames about its look, used by the
            filter and the predictive streams (:mod:`hbni_pyro.models.sequence.correlation`); fits of a model with
            ``correlated_frames`` estimate it from their sequences, and it must be 0 under other models.
    """

    samples: dict[str, Tensor]
    class_prior: Tensor
    hyperprior: HyperPrior = field(default_factory=HyperPrior)
    label_probs: Tensor | None = None
    info: dict[str, Any] = field(default_factory=dict)
    model: str = "paper"
    class_names: tuple[str, ...] | None = None
    frame_correlation: float = 0.0

    def __post_init__(self) -> None:
        self.model = self.noise_model.name
        self.class_names = as_names("class_names", self.class_names, self.num_classes)
        rho = as_float("frame_correlation", self.frame_correlation, -1.0, 1.0, low_open=True, high_open=True)
        if rho != 0.0 and not self.noise_model.correlated_frames:
            raise ValueError(f"frame_correlation: the {self.model!r} model draws frames i.i.d., expected 0, got {rho}")
        self.frame_correlation = rho
        shapes = self.noise_model.site_shapes(self.num_classes)
        missing = [k for k in shapes if k not in self.samples]
        if missing:
            raise ValueError(f"samples: missing sites {missing}, expected {list(shapes)} for model {self.model!r}")
        first = next(iter(shapes))
        lead = self.samples[first].shape[:2]
        if self.samples[first].dim() != 2 + len(shapes[first]):
            raise ValueError(
                f"samples[{first!r}]: expected shape (chains, draws, *{shapes[first]}), got {tuple(self.samples[first].shape)}"
            )
        for k, shape in shapes.items():
            if tuple(self.samples[k].shape) != tuple(lead) + shape:
                raise ValueError(
                    f"samples[{k!r}]: expected shape {tuple(lead) + shape}, got {tuple(self.samples[k].shape)}"
                )
            x = self.samples[k]
            if has_values(x) and not bool(torch.isfinite(x).all()):
                raise ValueError(f"samples[{k!r}]: expected finite draws, got NaN or infinite ones")
            if has_values(x) and k in self.noise_model.positive_sites and bool((x <= 0).any()):
                raise ValueError(f"samples[{k!r}]: expected draws > 0, got {float(x.min()):g}")
        as_class_prior(self.class_prior, self.num_classes)

    def named(self, class_names: Any) -> "HBNIPosterior":
        """A copy whose classes are called ``class_names`` (``M`` distinct names, in the outputs' column order):
        how a posterior fitted without names gets them (``posterior.named([...]).save(path)``)."""
        if class_names is None:
            raise TypeError("class_names: expected a sequence of names, got NoneType")
        return dataclasses.replace(self, info=dict(self.info), class_names=class_names)

    def match_names(self, class_names: Any, what: str) -> "HBNIPosterior":
        """This posterior with its class names, checked against ``class_names`` given where it meets other named
        objects (``what`` names that argument in messages).

        A named posterior needs no ``class_names`` (``None``) and refuses other ones, or its own in another order;
        an unnamed one takes ``class_names`` (a copy named so), and without them is refused with how to name it.

        Raises:
            ValueError: the names differ from the posterior's (both lists named), or neither side has any.
        """
        if self.class_names is not None:
            if class_names is not None and tuple(class_names) != self.class_names:
                raise ValueError(
                    f"{what}: expected the posterior's classes in its column order {list(self.class_names)}, "
                    f"got {list(class_names) if not isinstance(class_names, str) else class_names!r}"
                )
            return self
        if class_names is None:
            raise ValueError(
                f"{what}: the posterior has no class names, so nothing says which of its columns is which class; "
                "give the names in its column order here, fit it with class_names=[...], or name its file: "
                "HBNIPosterior.load(path).named([...]).save(path)"
            )
        return self.named(as_names(what, class_names, self.num_classes))

    @property
    def noise_model(self) -> NoiseModel:
        """The spec of :attr:`model` (:mod:`hbni_pyro.models`)."""
        return noise_model(self.model)

    @property
    def device(self) -> torch.device:
        """The device every tensor of the posterior is on."""
        return next(iter(self.samples.values())).device

    def to(self, device: str | torch.device) -> "HBNIPosterior":
        """A copy with every tensor on ``device`` (filters, tables and predictive draws then run there)."""
        device = as_device("device", device)
        moved = {k: v.to(device) for k, v in self.samples.items()}
        return dataclasses.replace(
            self,
            samples=moved,
            class_prior=self.class_prior.to(device),
            label_probs=None if self.label_probs is None else self.label_probs.to(device),
            info=dict(self.info),
        )

    @property
    def num_classes(self) -> int:
        return self.noise_model.num_classes(self.samples)

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
        ``prob`` interval's quantiles (``q5``, ``q95`` for 0.9; ``prob`` in ``(0, 1)``), ESS
        (:func:`effective_sample_size`) and split R-hat (``pyro.ops.stats``). Memory and time grow linearly with
        the draws."""
        prob = as_float("prob", prob, 0.0, 1.0, low_open=True, high_open=True)
        lo, hi = (1 - prob) / 2, (1 + prob) / 2
        out: dict[str, dict[str, float]] = {}
        for name, x in self.scalar_sites().items():
            flat = x.reshape(-1)
            q = quantiles(flat, (lo, hi))
            rhat = (
                split_gelman_rubin(x, chain_dim=0, sample_dim=1) if self.num_draws >= 4 else torch.tensor(float("nan"))
            )
            out[name] = {
                "mean": float(flat.mean()),
                "sd": float(flat.std()),
                f"q{lo * 100:g}": float(q[0]),
                f"q{hi * 100:g}": float(q[1]),
                "ess": effective_sample_size(x),
                "r_hat": float(rhat),
            }
        return out

    def scalar_sites(self) -> dict[str, Tensor]:
        """Every free scalar of the posterior as ``(chains, draws)``, named ``site[i, j]``."""
        sites: dict[str, Tensor] = {}
        for name, x in self.samples.items():
            shape = x.shape[2:]
            for index in (
                torch.cartesian_prod(*(torch.arange(n) for n in shape)).reshape(-1, len(shape)).tolist()
                if shape
                else [[]]
            ):
                if not self.noise_model.free_entry(name, index):
                    continue
                label = f"{name}[{', '.join(map(str, index))}]" if index else name
                sites[label] = x[(slice(None), slice(None), *index)]
        return sites

    def sample_outputs(self, true_class: int, n: int, seed: int = 0) -> Tensor:
        """Posterior-predictive classifier outputs ``(n, M)`` for class ``true_class``, each from its own
        posterior draw (and, under the sequence model, its own sequence)."""
        true_class = self._check_class(true_class)
        return self.sample_streams(true_class, as_int("n", n, minimum=1), 1, seed)[:, 0]

    def sample_streams(
        self,
        true_class: int,
        num_streams: int,
        num_frames: int,
        seed: int = 0,
        *,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """Posterior-predictive output streams ``(num_streams, num_frames, M)`` of new class-``true_class`` objects.

        Each stream takes one posterior draw; its frames are then i.i.d. given it (frame-level
        models) or share one new look (the sequence model), about which they scatter with the lag-1 correlation
        :attr:`frame_correlation`. ``generator``, when given, is used (and
        advanced) instead of a new one seeded with ``seed``; it must be on the posterior's device. The
        streams are drawn there; on ``meta`` they are shapes without values (no generator).
        """
        true_class = self._check_class(true_class)
        num_streams, num_frames = (
            as_int("num_streams", num_streams, minimum=1),
            as_int("num_frames", num_frames, minimum=1),
        )
        if generator is not None and not isinstance(generator, torch.Generator):
            raise TypeError(f"generator: expected a torch.Generator or None, got {type(generator).__name__}")
        g = (
            torch_generator(seed, self.device)
            if generator is None
            else as_generator("generator", generator, self.device)
        )
        draws = self.draws()
        first = next(iter(draws.values()))
        idx = torch.randint(first.shape[0], (num_streams,), generator=g, device=self.device)
        chosen = {k: v[idx] for k, v in draws.items()}
        if self.noise_model.correlated_frames:
            return self.noise_model.sample_streams(chosen, true_class, num_frames, g, self.frame_correlation)
        return self.noise_model.sample_streams(chosen, true_class, num_frames, g)

    def _check_class(self, true_class: int) -> int:
        if not 0 <= as_int("true_class", true_class) < self.num_classes:
            raise ValueError(f"true_class: expected an int in [0, {self.num_classes}), got {true_class!r}")
        return int(true_class)

    def save(self, path: str | os.PathLike) -> Path:
        """Write draws and metadata to one safetensors file, atomically (from any device; the file holds CPU tensors)."""
        tensors = {
            k: v.cpu().clone() for k, v in self.samples.items()
        }  # one buffer each, even if two sites share memory
        tensors["class_prior"] = self.class_prior.cpu()
        if self.label_probs is not None:
            tensors["label_probs"] = self.label_probs.cpu()
        meta = {
            "model": self.model,
            "hyperprior": self.hyperprior.as_dict(),
            "info": self.info,
            "class_names": None if self.class_names is None else list(self.class_names),
            "frame_correlation": self.frame_correlation,
        }
        return save_tensors(path, _KIND, tensors, meta, version=_VERSION)

    @classmethod
    def load(cls, path: str | os.PathLike, device: str | torch.device | None = None) -> "HBNIPosterior":
        """Read a file written by :meth:`save` onto ``device`` (``None``: the CPU); a corrupt or foreign file
        raises ``ValueError``."""
        if device is not None:
            return cls.load(path).to(device)
        tensors, meta = load_tensors(path, _KIND, version=_VERSION)
        model = meta.get("model", "paper")
        if not isinstance(model, str) or model not in model_names():
            raise ValueError(
                f"path: {str(path)!r} names an unknown noise model {model!r}, expected one of {model_names()}"
            )
        spec = noise_model(model)
        try:
            num_classes = spec.num_classes(tensors)
            return cls(
                samples={k: tensors[k] for k in spec.site_shapes(num_classes)},
                class_prior=tensors["class_prior"],
                hyperprior=HyperPrior(**meta["hyperprior"]),
                label_probs=tensors.get("label_probs"),
                info=meta.get("info", {}),
                model=model,
                class_names=meta.get("class_names"),
                frame_correlation=meta.get("frame_correlation", 0.0),
            )
        except KeyError as exc:
            raise ValueError(f"path: {str(path)!r} is an incomplete saved {_KIND} (missing {exc})") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None

    def to_arviz(self) -> Any:
        """An ``arviz.InferenceData`` with the draws (needs ArviZ: the ``analysis`` extra)."""
        arviz = require("arviz", "analysis", "HBNIPosterior.to_arviz()")
        return arviz.from_dict(
            posterior={k: v.numpy() for k, v in self.samples.items()},
            dims=self.noise_model.arviz_dims,
            coords={
                "class": list(range(self.num_classes)),
                "class_to": list(range(self.num_classes)),
                "coord": list(range(self.num_classes - 1)),
            },
        )

    def __repr__(self) -> str:
        head = f"HBNIPosterior(model={self.model!r}, M={self.num_classes}, chains={self.num_chains}, draws={self.num_draws}"
        if "theta" in self.samples:
            head += ", theta mean=[" + ", ".join(f"{float(v):.3g}" for v in self.theta_point()) + "]"
        if self.frame_correlation:
            head += f", frame_correlation={self.frame_correlation:.3f}"
        return head + f", method={self.info.get('method')!r})"


def quantiles(x: Tensor, probs: tuple[float, ...]) -> list[float]:
    """Quantiles of the 1-D ``x`` at ``probs``, interpolated linearly between order statistics as
    ``torch.quantile`` does, by selection (``kthvalue``): linear memory, and no size limit."""
    n = x.numel()
    out = []
    for p in probs:
        pos = p * (n - 1)
        below, above = math.floor(pos), math.ceil(pos)
        a = float(torch.kthvalue(x, below + 1).values)
        b = a if above == below else float(torch.kthvalue(x, above + 1).values)
        out.append(a + (b - a) * (pos - below))
    return out


_FFT_BLOCK = 2**21
"""Most padded entries transformed at once by :func:`effective_sample_size` (16 MB of float64)."""


def effective_sample_size(x: Tensor) -> float:
    """Effective sample size of the draws ``x (chains, draws)`` of one scalar, in memory linear in the draws.

    The estimator of ``pyro.ops.stats.effective_sample_size`` (Stan's: Geyer's initial monotone sequence on the
    chains' pooled autocorrelation, ``rho_k = 1 - (W - mean_c gamma_ck) / var+``), with each chain's
    autocovariance ``gamma_ck`` from one FFT (as ArviZ computes it) and the monotone sequence by a running
    minimum; pyro's running minimum builds a ``draws x draws`` matrix (320 GB at 400 000 draws). NaN when every
    draw is equal, as pyro's.
    """
    x = x.to(DTYPE)
    chains, n = x.shape
    if n < 2:
        return float("nan")
    size = 2 * next_fast_len(n)
    gamma = torch.zeros(n, dtype=DTYPE, device=x.device)  # sum over chains of each chain's autocovariance
    for block in x.split(max(1, _FFT_BLOCK // size)):  # a few chains at a time: bounded temporaries
        spectrum = torch.fft.rfft(block - block.mean(1, keepdim=True), n=size)
        gamma += torch.fft.irfft(spectrum.real.square() + spectrum.imag.square(), n=size)[:, :n].sum(0)
    gamma /= chains * torch.arange(n, 0, -1, dtype=DTYPE, device=x.device)
    var_within = x.var(1).mean()
    var_plus = (n - 1) / n * var_within
    if chains > 1:
        var_plus = var_plus + x.mean(1).var()
    else:
        var_within = var_plus
    rho = (var_plus - var_within + gamma) / var_plus
    rho[0] = 1.0
    pairs = rho[: n - n % 2].reshape(-1, 2).sum(1)
    tau = -1 + 2 * pairs[0]
    if pairs.numel() > 1:
        tau = tau + 2 * torch.cummin(pairs[1:].clamp(min=0), 0).values.sum()
    return float(chains * n / tau)


def posterior_from_samples(
    samples: dict[str, Tensor], class_prior: Tensor, hyperprior: HyperPrior, model: str = "paper", **kwargs: Any
) -> HBNIPosterior:
    """Build a posterior from ``(chains, draws, ...)`` tensors, cast to float64."""
    samples = {k: v.to(DTYPE) for k, v in samples.items()}
    return HBNIPosterior(samples, class_prior.to(DTYPE), hyperprior, model=model, **kwargs)
