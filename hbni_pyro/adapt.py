"""Adapting a fitted sequence model to a new place from the robot's own streams there, labelled or not.

A classifier's noise depends on where it looks: at a new place (other light, weather, camera) a posterior
fitted at the old place promises more than its labels keep. :func:`adapt` fits the sequence model again on the new
place's sequences, any number of them labelled and the rest not (their classes are latent and sampled), with the
class looks' prior anchored at the old posterior's (:class:`~hbni_pyro.shift_prior.ShiftPrior`: every class moved
by a shared scale and offset, plus a little on its own) and the class mix of the unlabelled sequences learnt
(a Dirichlet prior), since a place's objects are rarely balanced. The old place's classes name the new clusters,
so no new-place label is needed; where labels exist they weigh in too.

The classes of unlabelled sequences are drawn in a compiled loop on the CPU
(:func:`hbni_pyro.kernels.sequence_numba.classes`): ``benchmarks/bench_adapt.py`` times a fit on thousands of them.
"""

from __future__ import annotations

from typing import Any

import torch

from hbni_pyro.fit import _check_settings, _finish, _fit_device, _fit_mh, _sequence_ids
from hbni_pyro.model import HyperPrior
from hbni_pyro.posterior import HBNIPosterior
from hbni_pyro.shift_prior import ShiftPrior
from hbni_pyro.validation import as_labels, as_outputs
from hbni_pyro.variants import noise_model
from hbni_infra.checks import as_float

DEFAULT_PREVALENCE = 1.0
"""Concentration of the symmetric Dirichlet prior on the class mix of the new place's sequences (uniform over mixes)."""


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
            (:class:`~hbni_pyro.shift_prior.ShiftPrior`).
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
    return _finish(fitted, spec, posterior.class_names, x, ids)
