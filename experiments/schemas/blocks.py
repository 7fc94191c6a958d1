"""Schemas of the config blocks that several experiments share: ``hbni``, planning ``study`` and the field kinds
of the noise studies (noise levels, imaging conditions).

Each block is a dataclass: Hydra types every key when it composes (a wrong type or an unknown key fails there,
naming the key), and each field's range (:mod:`experiments.schemas.fields`) is checked before any work starts.
Messages name the field; :func:`experiments.schemas.check_settings` prefixes the block's path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from experiments.schemas.fields import choice, count, ranged
from experiments.schemas.targets import signature_defaults, target_schema
from hbni_pyro import HBNIFilter, fit, model_names
from hbni_pyro.fit import METHODS

HyperPriorBlock = target_schema("hbni_pyro.HyperPrior")
_FIT = signature_defaults(fit)
_FILTER = signature_defaults(HBNIFilter)


def _check_theta(name: str, theta: list[float]) -> None:
    if len(theta) < 2 or any(not (math.isfinite(t) and t > 0) for t in theta):
        raise ValueError(f"{name}: expected at least 2 noise levels > 0, all finite, got {list(theta)}")


def check_conditions(name: str, overrides: dict[str, Any] | None) -> None:
    from classifiers.data import get_conditions

    try:
        get_conditions("mission", **(overrides or {}))
    except (TypeError, ValueError) as exc:
        message = str(exc).removeprefix("conditions: ")
        raise ValueError(f"{name}: {message}") from None


def noise_levels() -> Any:
    """At least two true noise levels ``theta``, each finite and > 0."""
    return ranged(_check_theta)


def imaging_conditions() -> Any:
    """Overrides of the ``mission`` imaging preset's fields (:func:`classifiers.data.get_conditions`), or ``None``."""
    return ranged(check_conditions)


@dataclass
class FitBlock:
    """``hbni.fit``: the MCMC settings of :func:`hbni_pyro.fit`, defaulting to its own, except ``num_chains``, which
    ``conf/hbni/default.yaml`` sets (the library's ``None`` is one chain per CPU core, which varies by machine)."""

    method: str = choice(METHODS, _FIT["method"])
    num_chains: int = count()
    num_samples: int = count(default=_FIT["num_samples"])
    warmup_steps: int = count(0, default=_FIT["warmup_steps"])

    def kwargs(self) -> dict[str, Any]:
        """The settings as keyword arguments of :func:`hbni_pyro.fit`."""
        return {"method": self.method, **self.sizes()}

    def sizes(self) -> dict[str, Any]:
        """The chains and draws alone, as keyword arguments of :func:`hbni_pyro.fit_many` (which runs MH)."""
        return {"num_chains": self.num_chains, "num_samples": self.num_samples, "warmup_steps": self.warmup_steps}


@dataclass
class FilterBlock:
    """``hbni.filter``: how the HBNI filter uses the posterior (:class:`hbni_pyro.HBNIFilter`'s default)."""

    mode: str = choice(HBNIFilter.MODES, _FILTER["mode"])


@dataclass
class HBNIBlock:
    """``hbni``: noise model, hyperprior, fitting settings and filter mode."""

    model: str = choice(model_names)
    hyperprior: Any = field(default_factory=HyperPriorBlock)
    fit: FitBlock = field(default_factory=FitBlock)
    filter: FilterBlock = field(default_factory=FilterBlock)


@dataclass
class PlanningStudy:
    """``study`` of the planning experiments: how controllers are searched and scored.

    ``shared_controller``: every planner searches one controller the whole team runs.
    """

    shared_controller: bool = MISSING
    reeval_rollouts: int = count(2)
    threads: int = count()


@dataclass
class BaselineStudy(PlanningStudy):
    """A planning ``study`` that also runs baselines and a G-DICE run seeded with the greedy controller.

    ``seeded`` holds :class:`decpomdp.search.PlannerConfig` overrides of the G-DICE preset for the seeded run.
    """

    random_controllers: int = count(2)
    seeded: dict[str, Any] = MISSING
    select_rollouts: int = count(2)


def check_seeded(planner: Any, seeded: dict[str, Any]) -> None:
    """Raise ``ValueError`` unless ``planner`` overridden by the ``seeded`` settings is a valid planner."""
    from hydra.utils import instantiate

    base = instantiate({k: getattr(planner, k) for k in planner.__dataclass_fields__})
    unknown = sorted(set(seeded) - set(base.__dataclass_fields__))
    if unknown:
        raise ValueError(f"study.seeded: unknown planner setting(s) {unknown}")
    try:
        base.replace(**seeded)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"study.seeded: {exc}") from None
