"""Schemas of the config blocks that several experiments share: ``hbni`` and planning ``study``.

Each block is a dataclass: Hydra types every key when it composes (a wrong type or an unknown
key fails there, naming the key), and :meth:`check` validates ranges before any work starts.
Messages name the field; :func:`experiments.schemas.check_config` prefixes the block's path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from experiments.schemas.targets import signature_defaults, target_schema
from hbni_infra.checks import as_choice, as_int
from hbni_pyro import HBNIFilter, fit
from hbni_pyro.fit import METHODS

HyperPriorBlock = target_schema("hbni_pyro.HyperPrior")
_FIT = signature_defaults(fit)
_FILTER = signature_defaults(HBNIFilter)


@dataclass
class FitBlock:
    """``hbni.fit``: the MCMC settings of :func:`hbni_pyro.fit`, defaulting to its own, except ``num_chains``, which
    ``conf/hbni/default.yaml`` sets (the library's ``None`` is one chain per CPU core, which varies by machine)."""

    method: str = _FIT["method"]
    num_chains: int = MISSING
    num_samples: int = _FIT["num_samples"]
    warmup_steps: int = _FIT["warmup_steps"]

    def check(self, path: str) -> None:
        as_choice("method", self.method, METHODS)
        as_int("num_chains", self.num_chains, 1)
        as_int("num_samples", self.num_samples, 1)
        as_int("warmup_steps", self.warmup_steps, 0)


@dataclass
class FilterBlock:
    """``hbni.filter``: how the HBNI filter uses the posterior (:class:`hbni_pyro.HBNIFilter`'s default)."""

    mode: str = _FILTER["mode"]

    def check(self, path: str) -> None:
        as_choice("mode", self.mode, HBNIFilter.MODES)


@dataclass
class HBNIBlock:
    """``hbni``: noise model, hyperprior, fitting settings and filter mode."""

    model: str = MISSING
    hyperprior: Any = field(default_factory=HyperPriorBlock)
    fit: FitBlock = field(default_factory=FitBlock)
    filter: FilterBlock = field(default_factory=FilterBlock)

    def check(self, path: str) -> None:
        from hbni_pyro import model_names

        as_choice("model", self.model, model_names())


@dataclass
class PlanningStudy:
    """``study`` of the planning experiments: how controllers are searched and scored.

    ``shared_controller``: every planner searches one controller the whole team runs.
    """

    shared_controller: bool = MISSING
    reeval_rollouts: int = MISSING
    threads: int = MISSING

    def check(self, path: str) -> None:
        as_int("reeval_rollouts", self.reeval_rollouts, 2)
        as_int("threads", self.threads, 1)


@dataclass
class BaselineStudy(PlanningStudy):
    """A planning ``study`` that also runs baselines and a G-DICE run seeded with the greedy controller.

    ``seeded`` holds :class:`decpomdp.search.PlannerConfig` overrides of the G-DICE preset for the seeded run.
    """

    random_controllers: int = MISSING
    seeded: dict[str, Any] = MISSING
    select_rollouts: int = MISSING

    def check(self, path: str) -> None:
        super().check(path)
        as_int("random_controllers", self.random_controllers, 2)
        as_int("select_rollouts", self.select_rollouts, 2)


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
