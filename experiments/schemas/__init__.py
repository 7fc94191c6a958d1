"""Typed settings of every experiment, built once from the composed config and checked before any work starts.

Each ``conf/experiment/<name>.yaml`` puts ``/schema: <name>`` first in its defaults: Hydra then types every key
while it composes, so a wrong type (``seed=abc``) or an unknown key fails there, naming the key. The entry point
(:mod:`experiments.run`) then builds the experiment's settings object once, :func:`build_settings`: the composed
config merged into the schema's dataclass (:func:`typed_settings`, which also rejects keys added with ``+``) and
every range checked (:func:`check_settings`: ``mission.threshold=1.5`` fails naming the key). Below the entry
point, functions take that object or its blocks, never the config.

A key the chosen experiment never reads (:func:`unread_settings`: ``hbni.model`` in ``hbni_toy``, a planner
setting its planner ignores) is refused when it is set (:func:`check_overrides`), naming the key and the
experiment: ``experiments.run`` checks a run's overrides before it starts, and a ``-m`` sweep checks every job's
before it launches any (:mod:`experiments.sweep`).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import hydra
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from decpomdp.search import gdice_config
from experiments.runs.paths import register_resolver
from experiments.schemas.fields import check_ranges
from experiments.schemas.mission_study import MISSION_VARIANTS, PLANNING_MODELS, Mission
from experiments.schemas.new_place_study import NewPlace
from experiments.schemas.noise_studies import (
    FilteringError,
    HBNIToy,
    MacroObservation,
    NoiseModels,
    PerceptionReplay,
    Stream,
)
from experiments.schemas.planning_studies import DPOMDPBenchmarks, DisasterReliefExperiment, PackageDeliveryExperiment
from experiments.schemas.root import Root
from experiments.schemas.targets import preset

__all__ = [
    "MISSION_VARIANTS",
    "PLANNING_MODELS",
    "SCHEMAS",
    "build_settings",
    "check_overrides",
    "check_settings",
    "compose_config",
    "compose_settings",
    "config_error",
    "gdice_node",
    "register",
    "typed_settings",
    "unread_settings",
]

SCHEMAS: dict[str, type[Root]] = {
    "hbni_toy": HBNIToy,
    "filtering_error": FilteringError,
    "macro_observation": MacroObservation,
    "perception_replay": PerceptionReplay,
    "package_delivery": PackageDeliveryExperiment,
    "disaster_relief": DisasterReliefExperiment,
    "dpomdp_benchmarks": DPOMDPBenchmarks,
    "mission": Mission,
    "mission_full": Mission,
    "stream": Stream,
    "noise_models": NoiseModels,
    "new_place": NewPlace,
}
"""Schema of each experiment, by its ``name``."""

CONF = Path(__file__).resolve().parents[1] / "conf"
"""The experiments' Hydra configs (``conf/`` of the checkout, ``experiments/conf`` of an installed wheel)."""

PLANNER = "decpomdp.search.PlannerConfig"
HYPERPRIOR = "hbni_pyro.HyperPrior"


@functools.cache
def register() -> None:
    """Store every experiment's schema as ``schema/<name>`` (package ``_global_``) in Hydra's ConfigStore (once per
    process: a later call finds them stored)."""
    register_resolver()
    store = ConfigStore.instance()
    for name, schema in SCHEMAS.items():
        store.store(group="schema", name=name, node=schema, package="_global_")
    store.store(group="planner", name="gdice", node=gdice_node())


def compose_config(overrides: Sequence[str] = (), *, return_hydra_config: bool = False) -> DictConfig:
    """The config that ``python -m experiments.run <overrides>`` composes (``experiment=<name>`` picks the
    experiment), with the schemas registered; unchecked (:func:`build_settings` checks it, as a run does)."""
    register()
    with hydra.initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return hydra.compose("config", overrides=list(overrides), return_hydra_config=return_hydra_config)


def compose_settings(overrides: Sequence[str] = ()) -> Root:
    """The settings a run of ``python -m experiments.run <overrides>`` builds (:func:`build_settings`)."""
    return build_settings(compose_config(overrides))


def gdice_node() -> dict[str, Any]:
    """``planner=gdice``: :func:`decpomdp.search.gdice_config` as a config node (what differs from the planner's
    defaults), its graph starting with all its ``num_nodes`` nodes whatever ``num_nodes`` is set to."""
    return preset(PLANNER, gdice_config(), start_nodes="${.num_nodes}")


def typed_settings(cfg: DictConfig) -> Root:
    """The composed config ``cfg`` (with or without its ``hydra`` node) as its experiment's schema object: types and
    keys checked (a key added with ``+`` that the schema lacks fails here), ranges not yet.

    Raises:
        ValueError: naming the key.
    """
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    try:
        plain = OmegaConf.to_container(OmegaConf.create(plain), resolve=True)
        name = plain.get("name")
        if name not in SCHEMAS:
            raise ValueError(f"name: unknown experiment {name!r}; expected one of {sorted(SCHEMAS)}")
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(SCHEMAS[name]), plain))
    except OmegaConfBaseException as exc:
        raise config_error(exc) from None


def config_error(exc: OmegaConfBaseException) -> ValueError:
    """``exc`` (raised while typing or resolving a config) as one line naming the key; a resolver that failed on a
    file or folder (``HBNI_PYRO_ROOT`` naming a file) is quoted in its own words."""
    key = getattr(exc, "full_key", None)
    cause: BaseException | None = exc
    while cause is not None and not isinstance(cause, OSError):
        cause = cause.__cause__ or cause.__context__
    message = str(cause) if cause is not None else str(exc).split("\n")[0]
    return ValueError(f"{key}: {message}" if key else message)


def check_settings(settings: Root) -> Root:
    """``settings`` once every range holds (:func:`experiments.schemas.fields.check_ranges`), else a ``ValueError``
    naming the key."""
    return check_ranges(settings)


def build_settings(cfg: DictConfig) -> Root:
    """The experiment's settings from its composed config, every type and range checked: what a run's entry point
    passes down (:func:`typed_settings`, then :func:`check_settings`)."""
    return check_settings(typed_settings(cfg))


def unread_settings(settings: Root) -> dict[str, str]:
    """Key -> why the experiment of ``settings`` never reads it.

    Each experiment's schema names its own (``unread``: a block it has no use for, such as ``hbni`` in a planning
    study, or a key its other settings make irrelevant, such as ``warm_planner`` without ``warm_start``); every
    hyperprior block adds the fields no noise model it fits reads (``noise_models``,
    :attr:`hbni_pyro.NoiseModel.hyperprior_fields`), and every planner block the settings its planner ignores
    (:meth:`decpomdp.search.PlannerConfig.ignored`).
    """
    from hydra.utils import instantiate

    from hbni_pyro import model_names, noise_model

    out = dict(settings.unread())
    models = settings.noise_models()
    if models and all(m in model_names() for m in models):  # else the model fails its own check, naming the key
        fields = {f for m in models for f in noise_model(m).hyperprior_fields}
        for path, block in _blocks(settings, HYPERPRIOR, ""):
            for f in dataclasses.fields(block):
                if f.name != "_target_" and f.name not in fields:
                    out[f"{path}.{f.name}"] = f"the {' and '.join(map(repr, models))} noise model reads no {f.name}"
    for path, block in _blocks(settings, PLANNER, ""):
        if any(path == key or path.startswith(f"{key}.") for key in out):
            continue
        try:
            planner = instantiate(block)
        except Exception:  # an invalid planner fails its own check, naming the key
            continue
        for setting in sorted(planner.ignored()):
            out[f"{path}.{setting}"] = (
                f"the planner {path} (phases {list(planner.phases)}, ce_result {planner.ce_result!r}) ignores {setting}"
            )
    return out


def _blocks(node: Any, target: str, path: str) -> list[tuple[str, Any]]:
    """(key, block) of every block below ``node`` (settings, a block, a dict of them) whose ``_target_`` is
    ``target``; a block set to null has none."""
    if getattr(node, "_target_", None) == target:
        return [(path, node)]
    if dataclasses.is_dataclass(node):
        items = [(f.name, getattr(node, f.name)) for f in dataclasses.fields(node)]
    elif isinstance(node, dict):
        items = list(node.items())
    else:
        return []
    return [item for key, value in items for item in _blocks(value, target, f"{path}.{key}" if path else str(key))]


def override_key(override: str) -> str:
    """The config key an override (``key=value``, ``+key=value``, ``group@package=option``) sets."""
    key = override.split("=", 1)[0].lstrip("+~")
    return key.split("@", 1)[1] if "@" in key else key.replace("/", ".")


def check_overrides(settings: Root, overrides: list[str]) -> None:
    """Raise ``ValueError`` naming the key and the experiment if an override (``key=value``, as on the command
    line) sets a key the experiment never reads (:func:`unread_settings`): the job would run as if it were not
    set, and a sweep over it would run the same job again and again."""
    unread = unread_settings(settings)
    for override in overrides:
        key = override_key(override)
        if key.startswith("hydra.") or key == "hydra":
            continue
        for prefix, why in unread.items():
            if key == prefix or key.startswith(f"{prefix}."):
                what = "it" if key == prefix else prefix
                raise ValueError(f"{key}: experiment {settings.name} never reads {what}: {why}; remove the setting")
