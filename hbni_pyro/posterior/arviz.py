"""A posterior as ArviZ's ``InferenceData``, so that ``az.loo``, ``az.compare`` and ``az.plot_ppc`` run on HBNI's
noise models fitted to a user's own outputs.

Groups (:func:`inference_data`):

- ``posterior``: every site by chain and draw, with named dims (``class``, ``class_to``, ``coord``, ``coord_to``) and
  the posterior's class names as the ``class`` coordinate.
- ``sample_stats``: ``lp``, the log prior plus log likelihood of each draw (classes summed out, looks integrated out);
  for an MH fit ``acceptance_rate``, the share of the Metropolis-Hastings moves of the draw that were accepted (a
  draw equal to the one before it is a rejected move; the first draw of a chain has none: NaN), and, under the
  paper's model, ``step_size_theta``, the scale of each class's log-theta random walk (frozen after warm-up; the
  fit keeps its mean over chains).
- ``observed_data``: ``outputs`` ``(frame, class)`` and ``labels`` ``(frame)`` (-1 unknown), as fitted.
- ``log_likelihood``: ``outputs``, the pointwise log likelihood of each unit: a **sequence** when the fit had sequence
  ids (its frames' joint density: under the sequence model its look integrated out, since its frames are
  exchangeable only given the look; under a frame-level model the sum over its frames, independent given theta),
  else a **frame**. Fitting the three models with the same ``sequence_ids`` gives them the same units, so ``az.compare``
  ranks them on one data set. A unit with a label is conditioned on it; an unlabelled one has its class summed out
  under the class prior. Densities are over the simplex's ``M - 1`` free coordinates for every model (the sequence
  model's log-ratio density with its Jacobian), so the models' values compare.
- ``posterior_predictive``: ``outputs`` ``(frame, class)`` replicated for ``predictive_draws`` draws spread evenly
  over the chains: each unit of the data again, as a new object of its class (its label, else a class drawn from its
  posterior given the unit and the draw): a frame-level model draws each frame given its class, the sequence model
  a new look and the sequence's frames about it (with the posterior's frame correlation).
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor

from hbni_infra.checks import as_int, as_seed
from hbni_infra.optional import require
from hbni_infra.streams import torch_generator

HBNIPosterior = Any
"""A fitted :class:`~hbni_pyro.HBNIPosterior` (this module is below it: the posterior's ``to_arviz`` calls it)."""

_CHUNK = 1 << 22
"""Most ``draws x outputs x classes`` entries of class terms evaluated at once."""


def unit_labels(posterior: HBNIPosterior) -> Tensor:
    """``(U,)`` the label of each likelihood unit of a fitted posterior (-1 unknown): its frames' under a frame-level
    model, its sequence's under a model with sequences."""
    labels, ids = posterior.labels, posterior.sequence_ids
    if not posterior.noise_model.sequences:
        return labels
    return torch.full((int(ids.max()) + 1,), -1, dtype=torch.long, device=ids.device).scatter_(0, ids, labels)


def class_terms(posterior: HBNIPosterior, draws: dict[str, Tensor]) -> Tensor:
    """``(S, U, M)``: each unit's log density under each class for ``draws`` (site -> ``(S, ...)``), without the
    class prior (the record's ``unit_log_lik``)."""
    spec = posterior.noise_model
    return spec.unit_log_lik(draws, posterior.outputs, posterior.sequence_ids)


def pointwise_log_likelihood(posterior: HBNIPosterior) -> tuple[Tensor, str]:
    """``(log likelihood (S, units), unit)`` of a fitted posterior's draws pooled over chains; ``unit`` is
    ``"sequence"`` or ``"frame"`` (see the module's notes)."""
    spec = posterior.noise_model
    if spec.unit_log_lik is None or posterior.outputs is None:
        raise ValueError(
            f"posterior: no pointwise likelihood (model {posterior.model!r}, fitted data "
            f"{'kept' if posterior.outputs is not None else 'not kept'}); fit it with hbni_pyro.fit"
        )
    obs, ids = posterior.outputs, posterior.sequence_ids
    labels, log_p = unit_labels(posterior), posterior.class_prior.log()
    known = labels >= 0
    draws = posterior.draws()
    total = next(iter(draws.values())).shape[0]
    step = max(1, _CHUNK // (obs.shape[0] * obs.shape[1]))
    parts = []
    for start in range(0, total, step):
        per_class = class_terms(posterior, {k: v[start : start + step] for k, v in draws.items()})
        fixed = per_class.gather(-1, labels.clamp_min(0).expand(per_class.shape[:-1]).unsqueeze(-1)).squeeze(-1)
        unit = torch.where(known, fixed, torch.logsumexp(per_class + log_p, -1))
        if not spec.sequences and ids is not None:  # a frame-level model's frames summed per sequence
            unit = unit.new_zeros(unit.shape[0], int(ids.max()) + 1).index_add_(1, ids, unit)
        parts.append(unit)
    return torch.cat(parts), "sequence" if ids is not None else "frame"


def acceptance_rate(posterior: HBNIPosterior) -> Tensor | None:
    """``(chains, draws)`` share of the MH-moved scalars of each draw that moved (NaN for a chain's first draw);
    ``None`` for a fit that did not run the MH kernel."""
    sites = posterior.noise_model.mh_sites
    if posterior.info.get("method") != "mh" or not sites:
        return None
    moved = torch.cat(
        [
            (x[:, 1:] != x[:, :-1]).reshape(x.shape[0], x.shape[1] - 1, -1).to(x.dtype)
            for name, x in posterior.samples.items()
            if name in sites
        ],
        -1,
    ).mean(-1)
    first = moved.new_full((moved.shape[0], 1), math.nan)
    return torch.cat([first, moved], 1)


def _predictive_picks(posterior: HBNIPosterior, predictive_draws: int) -> Tensor:
    """``(chains, d)`` draw indices spread evenly over each chain, ``d = ceil(predictive_draws / chains)``."""
    per_chain = min(math.ceil(predictive_draws / posterior.num_chains), posterior.num_draws)
    return torch.linspace(0, posterior.num_draws - 1, per_chain).round().long()


def posterior_predictive(posterior: HBNIPosterior, predictive_draws: int, seed: int) -> Tensor:
    """``(chains, d, N, M)`` replicated outputs of a fitted posterior (see the module's notes)."""
    spec, obs, ids = posterior.noise_model, posterior.outputs, posterior.sequence_ids
    picks = _predictive_picks(posterior, predictive_draws)
    chains = posterior.num_chains
    draws = {k: v[:, picks].reshape((-1,) + v.shape[2:]) for k, v in posterior.samples.items()}  # (chains * d, ...)
    g = torch_generator(seed, posterior.device)
    per_class = class_terms(posterior, draws) + posterior.class_prior.log()
    labels = unit_labels(posterior)
    classes = torch.where(labels >= 0, labels.clamp_min(0), _categorical(per_class, g))  # (S, U)
    S, N, M = classes.shape[0], obs.shape[0], obs.shape[1]
    out = obs.new_zeros(S, N, M)
    if spec.sequences:
        order = torch.argsort(ids, stable=True)
        counts = torch.bincount(ids)
        position = torch.empty_like(ids)
        position[order] = torch.arange(N, device=ids.device) - torch.repeat_interleave(
            counts.cumsum(0) - counts, counts
        )
        length, extra = int(counts.max()), (posterior.frame_correlation,)
    else:  # each frame its own unit, one frame long
        ids = torch.arange(N, device=obs.device)
        position, length, extra = torch.zeros_like(ids), 1, ()
    for m in range(M):
        rows, units = (classes == m).nonzero(as_tuple=True)
        if not rows.numel():
            continue
        streams = spec.sample_streams({k: v[rows] for k, v in draws.items()}, m, length, g, *extra)  # (n, T, M)
        pair = torch.full((S, classes.shape[1]), -1, dtype=torch.long, device=obs.device)
        pair[rows, units] = torch.arange(rows.numel(), device=obs.device)
        chosen = pair[:, ids]  # (S, N): the stream of each draw's frame, -1 where its unit is of another class
        hit = chosen >= 0
        out[hit] = streams[chosen[hit], position.expand(S, N)[hit]]
    return out.reshape(chains, -1, N, M)


def _categorical(logits: Tensor, generator: torch.Generator) -> Tensor:
    """One class per row of ``logits (..., M)``, drawn with ``generator`` (inverse CDF)."""
    cdf = torch.softmax(logits, -1).cumsum(-1)
    u = torch.rand(logits.shape[:-1] + (1,), generator=generator, dtype=cdf.dtype, device=cdf.device)
    return (u * cdf[..., -1:] > cdf).sum(-1).clamp_max(logits.shape[-1] - 1)


def inference_data(posterior: HBNIPosterior, predictive_draws: int = 200, seed: int = 0) -> Any:
    """The ``arviz.InferenceData`` of ``posterior`` (the module's notes say what each group holds); the data groups
    need a posterior that kept its fitted data (``hbni_pyro.fit``'s do)."""
    az = require("arviz", "analysis", "HBNIPosterior.to_arviz()")
    predictive_draws = as_int("predictive_draws", predictive_draws, minimum=0)
    seed = as_seed("seed", seed)
    M, chains, n = posterior.num_classes, posterior.num_chains, posterior.num_draws
    names = list(posterior.class_names) if posterior.class_names is not None else list(range(M))
    coords: dict[str, Any] = {"class": names, "class_to": names, "coord": list(range(M - 1))}
    coords["coord_to"] = coords["coord"]
    dims = dict(posterior.noise_model.arviz_dims)
    groups: dict[str, Any] = {"posterior": {k: v.cpu().numpy() for k, v in posterior.samples.items()}}
    stats = {}
    accepted = acceptance_rate(posterior)
    if accepted is not None:
        stats["acceptance_rate"] = accepted.cpu().numpy()
    steps = posterior.info.get("step_size_theta")
    if steps is not None:
        stats["step_size_theta"] = torch.tensor(steps, dtype=torch.float64).expand(chains, n, M).numpy()
        dims["step_size_theta"] = ["class"]
    if posterior.outputs is not None and posterior.noise_model.unit_log_lik is not None:
        log_lik, unit = pointwise_log_likelihood(posterior)
        log_prior = posterior.noise_model.log_prior(posterior.draws(), posterior.hyperprior)
        stats["lp"] = (log_prior + log_lik.sum(-1)).reshape(chains, n).cpu().numpy()
        groups["log_likelihood"] = {"outputs": log_lik.reshape(chains, n, -1).cpu().numpy()}
        groups["observed_data"] = {"outputs": posterior.outputs.cpu().numpy(), "labels": posterior.labels.cpu().numpy()}
        dims["outputs"], dims["labels"] = ["frame", "class"], ["frame"]
        coords["frame"] = list(range(posterior.outputs.shape[0]))
        if predictive_draws:
            groups["posterior_predictive"] = {
                "outputs": posterior_predictive(posterior, predictive_draws, seed).cpu().numpy()
            }
        loo_dims = {"outputs": [unit]}
        coords[unit] = list(range(log_lik.shape[1]))
    else:
        loo_dims = {}
    groups["sample_stats"] = stats
    data = az.from_dict(**groups, coords=coords, dims=dims)
    if "log_likelihood" in groups:  # the log likelihood's unit differs from the observed outputs' frame
        data.log_likelihood = az.from_dict(
            log_likelihood=groups["log_likelihood"], coords=coords, dims=loo_dims
        ).log_likelihood
    return data
