"""Typed schemas of every experiment's config, checked before any work starts.

Each ``conf/experiment/<name>.yaml`` puts ``/schema: <name>`` first in its defaults: Hydra then
types every key while it composes, so a wrong type (``seed=abc``) or an unknown key fails there,
naming the key. :func:`check_config` then merges the composed config into the schema once more
(which also rejects keys added with ``+``) and checks every range (``mission.threshold=1.5``),
naming the key; :mod:`experiments.run` calls it before the experiment does anything.

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

from experiments.schemas.studies import SCHEMAS
from decpomdp.search import gdice_config
from experiments.runs.paths import register_resolver
from experiments.schemas.targets import join_key, preset

__all__ = ["SCHEMAS", "check_config", "check_overrides", "compose_config", "gdice_node", "register", "unread_settings"]

CONF = Path(__file__).resolve().parents[1] / "conf"
"""The experiments' Hydra configs (``conf/`` of the checkout, ``experiments/conf`` of an installed wheel)."""

PLANNER = "decpomdp.search.PlannerConfig"


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
    experiment), with the schemas registered; unchecked (:func:`check_config` checks it, as a run does)."""
    register()
    with hydra.initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return hydra.compose("config", overrides=list(overrides), return_hydra_config=return_hydra_config)


def gdice_node() -> dict[str, Any]:
    """``planner=gdice``: :func:`decpomdp.search.gdice_config` as a config node (what differs from the planner's
    defaults), its graph starting with all its ``num_nodes`` nodes whatever ``num_nodes`` is set to."""
    return preset(PLANNER, gdice_config(), start_nodes="${.num_nodes}")


def check_config(cfg: DictConfig) -> None:
    """Raise ``ValueError`` naming the key if ``cfg`` does not fit its experiment's schema.

    Args:
        cfg: a composed config (with or without its ``hydra`` node).
    """
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)
    plain = OmegaConf.to_container(OmegaConf.create(plain), resolve=True)
    name = plain.get("name")
    if name not in SCHEMAS:
        raise ValueError(f"name: unknown experiment {name!r}; expected one of {sorted(SCHEMAS)}")
    try:
        typed = OmegaConf.merge(OmegaConf.structured(SCHEMAS[name]), plain)
        obj = OmegaConf.to_object(typed)
    except OmegaConfBaseException as exc:
        key = getattr(exc, "full_key", None)
        message = str(exc).split("\n")[0]
        raise ValueError(f"{key}: {message}" if key else message) from None
    _check(obj, "")


PLANNER = "decpomdp.search.PlannerConfig"
HYPERPRIOR = "hbni_pyro.HyperPrior"


def unread_settings(cfg: DictConfig) -> dict[str, str]:
    """Key -> why the experiment of the composed config ``cfg`` never reads it.

    Each experiment's schema names its own (``unread``: a block it has no use for, such as ``hbni`` in a planning
    study, or a key its other settings make irrelevant, such as ``warm_planner`` without ``warm_start``); every
    hyperprior block adds the fields no noise model it fits reads (``noise_models``,
    :attr:`hbni_pyro.NoiseModel.hyperprior_fields`), and every planner block the settings its planner
    ignores (:meth:`decpomdp.search.PlannerConfig.ignored`).
    """
    from hydra.utils import instantiate

    if cfg.get("name") not in SCHEMAS:
        return {}
    schema = SCHEMAS[cfg.name]
    out = dict(schema.unread(cfg))
    models = schema.noise_models(cfg)
    if models:
        from hbni_pyro import model_names, noise_model

        if all(m in model_names() for m in models):  # else the model fails its own check, naming the key
            fields = {f for m in models for f in noise_model(m).hyperprior_fields}
            for path, block in _blocks(cfg, HYPERPRIOR, ""):
                for name in block:
                    if name != "_target_" and name not in fields:
                        out[f"{path}.{name}"] = f"the {' and '.join(map(repr, models))} noise model reads no {name}"
    for path, block in _blocks(cfg, PLANNER, ""):
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


def _blocks(node: Any, target: str, path: str) -> list[tuple[str, DictConfig]]:
    """(key, block) of every block of ``node`` whose ``_target_`` is ``target``."""
    if not isinstance(node, DictConfig) or node._is_none() or node._is_missing():  # a block set to null
        return []
    if node.get("_target_") == target:
        return [(path, node)]
    return [
        item
        for key in node
        if key != "hydra"
        for item in _blocks(node._get_node(key), target, f"{path}.{key}" if path else str(key))
    ]


def override_key(override: str) -> str:
    """The config key an override (``key=value``, ``+key=value``, ``group@package=option``) sets."""
    key = override.split("=", 1)[0].lstrip("+~")
    return key.split("@", 1)[1] if "@" in key else key.replace("/", ".")


def check_overrides(cfg: DictConfig, overrides: list[str]) -> None:
    """Raise ``ValueError`` naming the key and the experiment if an override (``key=value``, as on the command
    line) sets a key the experiment never reads (:func:`unread_settings`): the job would run as if it were not
    set, and a sweep over it would run the same job again and again."""
    unread = unread_settings(cfg)
    for override in overrides:
        key = override_key(override)
        if key.startswith("hydra.") or key == "hydra":
            continue
        for prefix, why in unread.items():
            if key == prefix or key.startswith(f"{prefix}."):
                what = "it" if key == prefix else prefix
                raise ValueError(f"{key}: experiment {cfg.name} never reads {what}: {why}; remove the setting")


def _check(obj: Any, path: str) -> None:
    """Call ``check(path)`` on every block, inner blocks first, prefixing errors with the block's key."""
    if not dataclasses.is_dataclass(obj):
        return
    for f in dataclasses.fields(obj):
        _check(getattr(obj, f.name), f"{path}.{f.name}" if path else f.name)
    if hasattr(obj, "check"):
        try:
            obj.check(path)
        except ValueError as exc:
            message = str(exc)
            if not path or message.startswith(f"{path}.") or message.startswith(f"{path}:"):
                raise
            raise ValueError(join_key(path, message, [f.name for f in dataclasses.fields(obj)])) from None
