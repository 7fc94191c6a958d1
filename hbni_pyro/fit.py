"""Fitting an HBNI noise model: the vectorised MH kernels, or Pyro NUTS as the reference.

``fit`` fits one dataset; ``fit_many`` fits many same-sized datasets in one vectorised MH
program (one block of chains per dataset), which is how a study that refits the model on
dozens of training sets, or a simulation-based calibration, stays fast. ``model`` picks the
variant (a name of :data:`hbni_pyro.models.NOISE_MODELS`); a sequence model needs ``sequence_ids``. ``adapt``
fits the sequence model again at a new place (other light, weather, camera), on the robot's own streams there,
labelled or not, with its class looks anchored at a posterior fitted at the old place
(:class:`~hbni_pyro.models.sequence.shift_prior.ShiftPrior`) and the class mix of the streams learnt; the old
place's classes name the new clusters, so no new-place label is needed.

MH runs on the device of the data, or of ``device=``: the data, every state tensor and the
kernel's ``torch.Generator`` live there, and so does the returned posterior. On the CPU the
paper's class move is the compiled one (:mod:`hbni_pyro.mcmc.class_move_numba`), so a seed
gives the same draws as ever; another device draws another random stream (the same law).
NUTS runs on the CPU only.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import pyro
import torch
from pyro import poutine
from pyro.infer import MCMC, NUTS, infer_discrete
from torch import Tensor

from hbni_pyro.distributions.prior import HyperPrior
from hbni_pyro.models import NoiseModel, noise_model
from hbni_pyro.models.sequence.correlation import estimate_frame_correlation
from hbni_pyro.models.sequence.program import SequenceStats, sequence_stats
from hbni_pyro.models.sequence.shift_prior import ShiftPrior
from hbni_pyro.posterior.posterior import HBNIPosterior, posterior_from_samples
from hbni_pyro.validation import DTYPE, as_class_prior, as_labels, as_outputs, as_sequence_ids
from hbni_infra.checks import SEED_LIMIT, as_device, as_float, as_int, as_names, as_seed
from hbni_infra.threads import single_thread

METHODS = ("mh", "nuts")
DEFAULT_CHAINS = {"mh": 16, "nuts": 2}
"""Chains per dataset when ``num_chains=None``. MH chains share one tensor program, and with labelled outputs
(sufficient statistics) they cost almost nothing extra; unknown classes cost a class move per output and
chain (7-12 CPU s a chain for 200 000 x 10 unlabelled outputs here). NUTS chains run one after another on these
CPUs."""
NUTS_SEED_LIMIT = 2**32
"""NUTS seeds Pyro's global streams, NumPy's among them, which take seeds below 2**32 only."""
DEFAULT_PREVALENCE = 1.0
"""Concentration of the symmetric Dirichlet prior on the class mix of the new place's sequences (uniform over mixes)."""


def fit(
    obs: Any,
    labels: Any = None,
    *,
    model: str | NoiseModel = "paper",
    sequence_ids: Any = None,
    method: str = "mh",
    num_chains: int | None = None,
    num_samples: int = 1000,
    warmup_steps: int = 500,
    seed: int = 0,
    progress: bool = True,
    hyperprior: HyperPrior | None = None,
    class_prior: Any = None,
    jit: bool = True,
    class_names: Any = None,
    device: str | torch.device | None = None,
) -> HBNIPosterior:
    """Infer a noise model's posterior from classifier outputs.

    Args:
        obs: ``(N, M)`` classifier outputs, rows on the simplex (exact zeros are floored).
        labels: ``(N,)`` true classes, ``-1`` where unknown; ``None`` means all unknown. Under the
            sequence model a sequence's outputs share one label.
        model: the noise model's name, ``"paper"`` (default), ``"confusion"``, ``"sequence"`` or
            another registered one (:func:`hbni_pyro.models.register`), or its spec.
        sequence_ids: ``(N,)`` integer id of each output's sequence (required by a sequence
            model; the others do not fit on them but check them as the sequence model does, so that switching
            ``model`` never hides ids that do not fit the outputs, and keep them as the units of their pointwise
            likelihood, :meth:`~HBNIPosterior.to_arviz`); a sequence's outputs in time order, from which a model
            with ``correlated_frames`` estimates :attr:`~HBNIPosterior.frame_correlation`.
        method: ``"mh"`` (the vectorised kernels) or ``"nuts"`` (Pyro NUTS on the Pyro model with
            the classes enumerated out, labels recovered by ``infer_discrete``).
        num_chains: chains (``None`` = ``DEFAULT_CHAINS[method]``).
        num_samples, warmup_steps: post-warm-up draws per chain and warm-up iterations.
        seed: same seed, same draws: an int in ``[0, 2**63)`` (``[0, 2**32)`` for NUTS).
        progress: show Pyro's progress bar.
        hyperprior: a :class:`HyperPrior` (``None`` = defaults).
        class_prior: ``(M,)`` prior ``p`` over classes (``None`` = uniform).
        jit: compile the NUTS potential with the PyTorch JIT (ignored by MH).
        class_names: ``M`` names of the classes, in column order, stored with the posterior (``None``: unnamed).
        device: where MH runs, a ``str`` or ``torch.device`` (``None``: the device of ``obs``); the data are
            moved there. NUTS runs on the CPU only: another device raises ``ValueError``, and so does ``"meta"``
            (MH needs values).

    Returns:
        An :class:`HBNIPosterior` with ``num_chains`` chains of ``num_samples`` draws, on ``device``.
    """
    x = as_outputs(obs, min_dim=2)
    if x.dim() != 2:
        raise ValueError(f"obs: expected shape (N, M), got {tuple(x.shape)}; use fit_many for a stack of datasets")
    y = None if labels is None else as_labels(labels, x.shape[0], x.shape[1])
    spec = noise_model(model)
    hp, p, chains, num_samples, warmup_steps, seed = _check_settings(
        method, num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, x.shape[1]
    )
    where = _fit_device(device, x, method)
    x, y, p = x.to(where), None if y is None else y.to(where), p.to(where)
    ids = _sequence_ids(spec, sequence_ids, x.shape[0], None if y is None else y.unsqueeze(0), where)
    kept = ids if ids is not None or sequence_ids is None else as_sequence_ids(sequence_ids, x.shape[0]).to(where)
    names = as_names("class_names", class_names, x.shape[1])
    settings = dict(
        chains=chains, num_samples=num_samples, warmup_steps=warmup_steps, seed=seed, progress=progress, hp=hp, p=p
    )
    if method == "mh":
        posterior = _fit_mh(spec, x.unsqueeze(0), None if y is None else y.unsqueeze(0), ids, **settings)[0]
    else:
        posterior = _fit_nuts(spec, x, y, ids, jit=jit, **settings)
    return _finish(posterior, spec, names, x, y, kept)


def fit_many(
    obs_sets: Any,
    labels: Any = None,
    *,
    model: str | NoiseModel = "paper",
    sequence_ids: Any = None,
    num_chains: int | None = None,
    num_samples: int = 1000,
    warmup_steps: int = 500,
    seed: int = 0,
    progress: bool = True,
    hyperprior: HyperPrior | None = None,
    class_prior: Any = None,
    class_names: Any = None,
    device: str | torch.device | None = None,
) -> list[HBNIPosterior]:
    """Fit ``D`` independent datasets ``obs_sets (D, N, M)`` with MH in one vectorised run.

    ``labels`` is ``None`` or ``(D, N)`` with -1 for unknown; ``sequence_ids (N,)`` is shared by the
    datasets. Returns ``D`` posteriors, each with ``num_chains`` chains; dataset ``d``'s chains see
    only dataset ``d``; ``class_names`` names the classes of all of them. ``device`` as in :func:`fit`.
    """
    x = as_outputs(obs_sets, min_dim=3, name="obs_sets")
    if x.dim() != 3:
        raise ValueError(f"obs_sets: expected shape (D, N, M), got {tuple(x.shape)}")
    y = None
    if labels is not None:
        y = torch.stack(
            [
                as_labels(row, x.shape[1], x.shape[2], name=f"labels[{d}]")
                for d, row in enumerate(torch.as_tensor(labels))
            ]
        )
        if y.shape[0] != x.shape[0]:
            raise ValueError(f"labels: expected {x.shape[0]} rows to match obs_sets, got {y.shape[0]}")
    spec = noise_model(model)
    hp, p, chains, num_samples, warmup_steps, seed = _check_settings(
        "mh", num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, x.shape[2]
    )
    where = _fit_device(device, x, "mh", name="obs_sets")
    x, y, p = x.to(where), None if y is None else y.to(where), p.to(where)
    ids = _sequence_ids(spec, sequence_ids, x.shape[1], y, where)
    kept = ids if ids is not None or sequence_ids is None else as_sequence_ids(sequence_ids, x.shape[1]).to(where)
    names = as_names("class_names", class_names, x.shape[2])
    posteriors = _fit_mh(spec, x, y, ids, chains, num_samples, warmup_steps, seed, progress, hp, p)
    return [
        _finish(posterior, spec, names, x[d], None if y is None else y[d], kept)
        for d, posterior in enumerate(posteriors)
    ]


def adapt(
    posterior: HBNIPosterior,
    obs: Any,
    labels: Any = None,
    *,
    sequence_ids: Any,
    shift_sd: float = 0.2,
    prevalence: float | None = DEFAULT_PREVALENCE,
    num_chains: int = 16,
    num_samples: int = 500,
    warmup_steps: int = 500,
    seed: int = 0,
    progress: bool = True,
    hyperprior: HyperPrior | None = None,
    device: str | torch.device | None = None,
) -> HBNIPosterior:
    """The sequence model fitted on a new place's sequences, its class looks anchored at ``posterior``'s.

    Args:
        posterior: a sequence-model posterior fitted at the old place (its class names name the new one's).
        obs: ``(N, M)`` classifier outputs at the new place, columns in ``posterior``'s class order.
        labels: ``(N,)`` true classes, ``-1`` where unknown (``None``: none known); constant within a sequence.
        sequence_ids: ``(N,)`` each output's sequence, its outputs in time order.
        shift_sd: how far one class's mean look may move apart from the shared move, per log-ratio coordinate
            (:class:`~hbni_pyro.models.sequence.shift_prior.ShiftPrior`).
        prevalence: concentration of the symmetric Dirichlet prior on the class mix of the sequences, which is
            learnt (its posterior mean and sd are in ``info["sites"]["prevalence"]``); ``None`` fixes it at the
            posterior's ``class_prior``. The returned posterior's ``class_prior``, which its filter uses, stays
            ``posterior``'s: the mix a robot meets on its mission is not that of the streams it adapted on.
        num_chains, num_samples, warmup_steps, seed, progress, hyperprior, device: as for :func:`hbni_pyro.fit`
            (``hyperprior=None``: ``posterior``'s).

    Returns:
        An :class:`~hbni_pyro.HBNIPosterior` of the sequence model; its ``info`` records the ``shift_prior`` and
        the shared move's scale and offset (``info["sites"]``).
    """
    if not isinstance(posterior, HBNIPosterior):
        raise TypeError(f"posterior: expected an HBNIPosterior, got {type(posterior).__name__}")
    prior = ShiftPrior.from_posterior(posterior, shift_sd=shift_sd)
    x = as_outputs(obs, posterior.num_classes, min_dim=2)
    if x.dim() != 2:
        raise ValueError(f"obs: expected shape (N, M), got {tuple(x.shape)}")
    y = None if labels is None else as_labels(labels, x.shape[0], x.shape[1])
    if prevalence is not None:
        prevalence = as_float("prevalence", prevalence, 0.0, low_open=True, high_open=True)
    spec = noise_model("sequence")
    hp = posterior.hyperprior if hyperprior is None else hyperprior
    hp, p, chains, num_samples, warmup_steps, seed = _check_settings(
        "mh", num_chains, num_samples, warmup_steps, seed, hp, posterior.class_prior.cpu(), x.shape[1]
    )
    where = _fit_device(device, x, "mh")
    x, y, p = x.to(where), None if y is None else y.to(where), p.to(where)
    ids = _sequence_ids(spec, sequence_ids, x.shape[0], None if y is None else y.unsqueeze(0), where)
    options = {"shift_prior": prior, "prevalence": prevalence}
    fitted = _fit_mh(
        spec,
        x.unsqueeze(0),
        None if y is None else y.unsqueeze(0),
        ids,
        chains,
        num_samples,
        warmup_steps,
        seed,
        progress,
        hp,
        p,
        kernel_options=options,
    )[0]
    fitted.info["shift_prior"] = prior.as_dict()
    fitted.info["prevalence_concentration"] = prevalence
    return _finish(fitted, spec, posterior.class_names, x, y, ids)


def _finish(
    posterior: HBNIPosterior, spec: NoiseModel, names: Any, x: Tensor, y: Tensor | None, ids: Tensor | None
) -> HBNIPosterior:
    """``posterior`` of the outputs ``x (N, M)`` (labels ``y``, sequence ids ``ids``), which it keeps, with its class
    names and, under a model with ``correlated_frames``, the frame correlation of its sequences."""
    posterior.class_names = names
    if spec.correlated_frames:
        posterior.frame_correlation = estimate_frame_correlation(x, ids)
    posterior.outputs, posterior.sequence_ids = x, ids
    posterior.labels = torch.full(x.shape[:1], -1, dtype=torch.long, device=x.device) if y is None else y
    return posterior


def _fit_device(device: Any, data: Tensor, method: str, name: str = "obs") -> torch.device:
    """The device a fit runs on: ``device`` (checked) or, when ``None``, that of ``data`` (the argument ``name``)."""
    where = data.device if device is None else as_device("device", device)
    source = f" (the device of {name})" if device is None else ""
    if method == "nuts" and where.type != "cpu":
        raise ValueError(f"device: method='nuts' runs on the CPU only, got {str(where)!r}{source}; use method='mh'")
    if where.type == "meta":
        raise ValueError(f"device: MH needs values, and 'meta' tensors carry shapes only{source}")
    return where


def _sequence_ids(
    spec: NoiseModel, sequence_ids: Any, num_obs: int, labels: Tensor | None, device: torch.device
) -> Tensor | None:
    """Validated ids remapped to ``0..K-1`` on ``device`` (``None`` for frame-level models, which still check ids
    they are given: ids that do not fit the outputs are a mistake in the data, whichever model reads them);
    ``labels`` (on ``device``) must agree within a sequence."""
    if not spec.sequences:
        if sequence_ids is not None:
            as_sequence_ids(sequence_ids, num_obs)
        return None
    if sequence_ids is None:
        raise ValueError(f"sequence_ids: the {spec.name!r} model needs the sequence id of every output, got None")
    ids = as_sequence_ids(sequence_ids, num_obs).to(device)
    for d, row in enumerate([] if labels is None else labels):
        high = torch.full((int(ids.max()) + 1,), -1, dtype=torch.long, device=ids.device).scatter_reduce(
            0, ids, row, "amax", include_self=False
        )
        low = torch.full_like(high, -1).scatter_reduce(0, ids, row, "amin", include_self=False)
        mixed = (high != low).nonzero()
        if mixed.numel():
            k = int(mixed[0])
            raise ValueError(
                f"labels: sequence {k} of dataset {d} mixes labels {sorted(set(row[ids == k].tolist()))}; "
                "the outputs of one sequence share one label (or all -1)"
            )
    return ids


def _check_settings(method, num_chains, num_samples, warmup_steps, seed, hyperprior, class_prior, num_classes):
    """Validated (hyperprior, class prior, chains, num_samples, warmup_steps, seed); numpy/torch ints accepted."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    chains = as_int("num_chains", DEFAULT_CHAINS[method] if num_chains is None else num_chains, minimum=1)
    sizes = as_int("num_samples", num_samples, minimum=1), as_int("warmup_steps", warmup_steps, minimum=0)
    hp = HyperPrior() if hyperprior is None else hyperprior
    if not isinstance(hp, HyperPrior):
        raise TypeError(f"hyperprior: expected a HyperPrior, got {type(hyperprior).__name__}")
    seed = as_seed("seed", seed, NUTS_SEED_LIMIT if method == "nuts" else SEED_LIMIT)
    return hp, as_class_prior(class_prior, num_classes), chains, *sizes, seed


def _stacked_stats(x: Tensor, y: Tensor | None, ids: Tensor) -> SequenceStats:
    num_seq = int(ids.max()) + 1
    labels = torch.full(x.shape[:2], -1, dtype=torch.long, device=x.device) if y is None else y
    per_set = [sequence_stats(x[d], ids, labels[d], num_seq) for d in range(x.shape[0])]
    return SequenceStats(*(torch.stack(parts) for parts in zip(*per_set)))


def _fit_mh(
    spec, x, y, ids, chains, num_samples, warmup_steps, seed, progress, hp, p, kernel_options=None
) -> list[HBNIPosterior]:
    """One vectorised MH run over the ``D`` datasets ``x (D, N, M)``; ``kernel_options`` go to the kernel. Sites in
    the kernel's ``summary_sites`` are summarised per dataset in the posterior's ``info["sites"]`` (mean and sd over
    the draws) instead of being kept as draws."""
    D = x.shape[0]
    kernel = spec.kernel(num_chains=D * chains, hyperprior=hp, class_prior=p, seed=seed, **(kernel_options or {}))
    mcmc = MCMC(kernel, num_samples=num_samples, warmup_steps=warmup_steps, disable_progbar=not progress)
    args = (_stacked_stats(x, y, ids),) if spec.sequences else (x, y)
    start = time.perf_counter()
    with single_thread():
        mcmc.run(*args)
    if x.device.type == "cuda":
        torch.cuda.synchronize(x.device)
    seconds = time.perf_counter() - start
    draws = {k: v[0].transpose(0, 1) for k, v in mcmc.get_samples(group_by_chain=True).items()}
    summarised = {k: (v := draws.pop(k)).reshape((D, -1) + v.shape[2:]) for k in getattr(kernel, "summary_sites", ())}
    label_probs = kernel.label_probs if ids is None else kernel.label_probs[:, ids]
    diag = kernel.diagnostics()
    info = {
        "method": "mh",
        "num_chains": chains,
        "num_samples": num_samples,
        "warmup_steps": warmup_steps,
        "seed": seed,
        "seconds": seconds,
        "datasets_in_run": D,
        "acceptance_rate": diag["acceptance rate"],
    }
    if "step size theta" in diag:
        info["step_size_theta"] = diag["step size theta"]
    return [
        posterior_from_samples(
            {k: v.reshape((D, chains) + v.shape[1:])[d] for k, v in draws.items()},
            p,
            hp,
            spec.name,
            label_probs=label_probs[d],
            info=dict(info, sites=_site_summaries(summarised, d)) if summarised else info,
        )
        for d in range(D)
    ]


def _site_summaries(summarised: dict[str, Tensor], d: int) -> dict[str, dict[str, Any]]:
    """Dataset ``d``'s mean and sd of each summarised site (``(D, draws, ...)`` tensors), as lists."""
    return {k: {"mean": v[d].mean(0).tolist(), "sd": v[d].std(0).tolist()} for k, v in summarised.items()}


def _fit_nuts(spec, x, y, ids, chains, num_samples, warmup_steps, seed, progress, hp, p, jit) -> HBNIPosterior:
    args = _nuts_args(spec, x, y, ids)
    pyro.set_rng_seed(seed)
    kernel = NUTS(spec.pyro_model, max_plate_nesting=spec.max_plate_nesting, jit_compile=jit, ignore_jit_warnings=True)
    start = time.perf_counter()
    with warnings.catch_warnings(), single_thread():
        warnings.filterwarnings("ignore", message="num_chains=.*more than available_cpu")
        mcmc = MCMC(
            kernel, num_samples=num_samples, warmup_steps=warmup_steps, num_chains=chains, disable_progbar=not progress
        )
        mcmc.run(*args, p, hp)
    seconds = time.perf_counter() - start
    raw = mcmc.get_samples(group_by_chain=True)
    divergences = mcmc.diagnostics().get("divergences", {})
    info = {
        "method": "nuts",
        "num_chains": chains,
        "num_samples": num_samples,
        "warmup_steps": warmup_steps,
        "seed": seed,
        "seconds": seconds,
        "jit": jit,
        "divergences": int(sum(len(v) for v in divergences.values())),
    }
    label_probs = recover_label_probs(spec.pyro_model, args, raw, p, hp, seed=seed)
    if ids is not None:
        label_probs = label_probs[ids]
    return posterior_from_samples(spec.nuts_sites(raw), p, hp, spec.name, label_probs=label_probs, info=info)


def _nuts_args(spec: NoiseModel, x: Tensor, y: Tensor | None, ids: Tensor | None) -> tuple:
    """The Pyro model's data arguments: ``(obs, labels)``, or padded sequences ``(obs, mask, labels)``."""
    if not spec.sequences:
        return (x, y)
    num_seq, M = int(ids.max()) + 1, x.shape[1]
    order = torch.argsort(ids, stable=True)
    counts = torch.bincount(ids, minlength=num_seq)
    pos = torch.arange(len(ids)) - torch.repeat_interleave(counts.cumsum(0) - counts, counts)
    padded = torch.full((num_seq, int(counts.max()), M), 1.0 / M, dtype=x.dtype)
    padded[ids[order], pos] = x[order]
    mask = torch.zeros(padded.shape[:2], dtype=torch.bool)
    mask[ids[order], pos] = True
    labels = None if y is None else torch.full((num_seq,), -1, dtype=torch.long).scatter_(0, ids, y)
    return (padded, mask, labels)


def recover_label_probs(
    model_fn: Callable,
    args: tuple,
    draws: dict[str, Tensor],
    class_prior: Tensor,
    hyperprior: HyperPrior,
    max_draws: int = 100,
    seed: int = 0,
) -> Tensor:
    """Posterior class probabilities of the training units (outputs, or sequences) by ``infer_discrete``.

    For up to ``max_draws`` evenly spaced continuous draws, the classes are sampled from their
    exact conditional (``temperature=1``) and their frequencies returned; labelled units are one-hot.
    ``args`` are the Pyro model's data arguments, whose last entry is the labels (or ``None``).
    """
    labels = args[-1]
    units, M = args[0].shape[0], args[0].shape[-1]
    flat = {k: v.reshape((-1,) + v.shape[2:]) for k, v in draws.items()}
    total = next(iter(flat.values())).shape[0]
    picks = torch.linspace(0, total - 1, min(max_draws, total)).round().long()
    known = torch.zeros(units, dtype=torch.bool) if labels is None else labels >= 0
    counts = torch.zeros(units, M, dtype=DTYPE)
    if known.any():
        counts[known] = torch.nn.functional.one_hot(labels[known], M).to(DTYPE) * len(picks)
    if (~known).any():
        pyro.set_rng_seed(seed)
        for i in picks.tolist():
            conditioned = poutine.condition(model_fn, data={k: v[i] for k, v in flat.items()})
            sampler = infer_discrete(conditioned, first_available_dim=-3, temperature=1)
            trace = poutine.trace(sampler).get_trace(*args, class_prior, hyperprior)
            counts[~known] += torch.nn.functional.one_hot(trace.nodes["c"]["value"].reshape(-1), M).to(DTYPE)
    return counts / len(picks)
