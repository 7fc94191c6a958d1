"""``NoiseModel``: everything the package needs to know about one noise-model variant.

A variant is one room of :mod:`hbni_pyro.models` (see :mod:`hbni_pyro.models.paper` for the smallest) whose
``__init__`` builds a ``NoiseModel``, and one line in :data:`hbni_pyro.models.NOISE_MODELS` (or a call to
:func:`hbni_pyro.models.register`). The fitting driver, the posterior, the filter, the
generative tables and simulation-based calibration read the variant only through this record.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

Draws = dict[str, Tensor]
"""Site name -> draws; the leading dims are the draws' (``(S,)`` pooled, ``(chains, draws)`` by chain)."""


def median_point(draws: Draws) -> Draws:
    """The plug-in draw ``(1, ...)``: the median of every site (concentrations are skewed)."""
    return {k: v.median(0).values.unsqueeze(0) for k, v in draws.items()}


def every_entry_free(site: str, index: list[int]) -> bool:
    """Every entry of every site is a free parameter."""
    return True


@dataclass(frozen=True)
class NoiseModel:
    """One noise-model variant.

    Attributes:
        name: the value of ``model=`` that selects it.
        summary: one line on what it models (shown in listings and errors).
        pyro_model: the Pyro program, called ``(*data, class_prior, hyperprior)`` where ``data`` is
            ``(obs (N, M), labels)`` or, for a sequence model, ``(padded (K, T, M), mask (K, T), labels (K,))``.
            NUTS runs on it with the classes enumerated out.
        kernel: the vectorised MH kernel class, ``kernel(num_chains=, hyperprior=, class_prior=, seed=)``; its
            ``setup`` takes ``(obs, labels)``, or the :class:`~hbni_pyro.models.sequence.program.SequenceStats` of a
            sequence model.
        evidence: the filter's evidence class over pooled draws (:mod:`hbni_pyro.models.paper.evidence`).
        site_shapes: ``M -> {site: per-draw shape}``; the first site's first axis indexes the classes.
        nuts_sites: the posterior sites from the Pyro program's sampled sites ``(chains, draws, ...)``.
        sample_streams: ``(draws, true_class, num_frames, generator) -> (n, num_frames, M)`` output
            streams, one per draw of ``draws`` (site -> ``(n, ...)``).
        sequences: fits take sequence ids, and a sequence's frames share a latent look.
        correlated_frames: ``sample_streams`` and ``evidence`` also take ``correlation``, the AR(1) lag-1
            correlation of a stream's frames about its look, and fits estimate it from their sequences
            (:mod:`hbni_pyro.models.sequence.correlation`; a sequence model only).
        max_plate_nesting: the Pyro program's plate depth (for NUTS).
        filter_draws: the filter's default number of draws (``None``: all).
        point_estimate: the filter's plug-in draw from pooled draws.
        free_entry: ``(site, index) -> bool``, whether an entry is a free parameter (summaries skip the others).
        positive_sites: the sites whose every entry is > 0 (concentrations, scales); a posterior refuses a draw
            that is not, as it refuses a NaN or infinite one in any site.
        arviz_dims: site -> dimension names for :meth:`~hbni_pyro.HBNIPosterior.to_arviz`.
        draw_prior: ``(hyperprior, M, n, generator) -> draws (n, ...)`` from the prior, for SBC (``None``: no SBC).
        simulate: ``(params, classes, num_frames, generator) -> (N, M)`` outputs of one dataset, for SBC.
        rank_statistics: draws ``(n, ...)`` -> name -> ``(n,)``, the scalars whose ranks SBC checks.
        hyperprior_fields: the :class:`~hbni_pyro.HyperPrior` fields the model reads (it ignores the others).
    """

    name: str
    summary: str
    pyro_model: Callable
    kernel: type
    evidence: type
    site_shapes: Callable[[int], dict[str, tuple[int, ...]]]
    nuts_sites: Callable[[Draws], Draws]
    sample_streams: Callable[[Draws, int, int, torch.Generator], Tensor]
    sequences: bool = False
    correlated_frames: bool = False
    max_plate_nesting: int = 1
    filter_draws: int | None = None
    point_estimate: Callable[[Draws], Draws] = median_point
    free_entry: Callable[[str, list[int]], bool] = every_entry_free
    positive_sites: tuple[str, ...] = ()
    arviz_dims: dict[str, list[str]] = field(default_factory=dict)
    draw_prior: Callable | None = None
    simulate: Callable | None = None
    rank_statistics: Callable[[Draws], dict[str, Tensor]] | None = None
    hyperprior_fields: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.correlated_frames and not self.sequences:
            raise ValueError(f"correlated_frames: the {self.name!r} model has no sequences to correlate frames in")

    @property
    def class_site(self) -> str:
        """The site whose first per-draw axis indexes the classes."""
        return next(iter(self.site_shapes(2)))

    def num_classes(self, samples: Draws, lead: int = 2) -> int:
        """``M`` from ``samples`` whose first ``lead`` dims are the draws' (2 by chain, 1 pooled)."""
        site = self.class_site
        if site not in samples:
            raise ValueError(
                f"samples: missing sites [{site!r}], expected {list(self.site_shapes(2))} for model {self.name!r}"
            )
        x = samples[site]
        if x.dim() <= lead:
            raise ValueError(
                f"samples[{site!r}]: expected {lead} draw dims and a class axis, got shape {tuple(x.shape)}"
            )
        return int(x.shape[lead])

    def __repr__(self) -> str:
        return f"NoiseModel({self.name!r}: {self.summary})"
