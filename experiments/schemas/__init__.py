"""Typed schemas of every experiment's config, checked before any work starts.

Each ``conf/experiment/<name>.yaml`` puts ``/schema: <name>`` first in its defaults: Hydra then
types every key while it composes, so a wrong type (``seed=abc``) or an unknown key fails there,
naming the key. :func:`check_config` then merges the composed config into the schema once more
(which also rejects keys added with ``+``) and checks every range (``mission.threshold=1.5``),
naming the key; :mod:`experiments.run` calls it before the experiment does anything.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from experiments.schemas.studies import SCHEMAS
from decpomdp.search import gdice_config
from experiments.schemas.targets import join_key, preset
from experiments.paths import register_resolver

__all__ = ["SCHEMAS", "check_config", "gdice_node", "register"]

PLANNER = "decpomdp.search.PlannerConfig"


def register() -> None:
    """Store every experiment's schema as ``schema/<name>`` (package ``_global_``) in Hydra's ConfigStore."""
    register_resolver()
    store = ConfigStore.instance()
    for name, schema in SCHEMAS.items():
        store.store(group="schema", name=name, node=schema, package="_global_")
    store.store(group="planner", name="gdice", node=gdice_node())


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


def check_overrides(cfg: DictConfig, overrides: list[str]) -> None:
    """Raise ``ValueError`` naming the key if an override (``key=value``, as on the command line) sets a planner
    setting that the chosen planner ignores (see :meth:`decpomdp.search.PlannerConfig.ignored`): a sweep over
    it would run the same job again and again."""
    from hydra.utils import instantiate

    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        parts = key.split(".")
        for cut in range(len(parts) - 1, 0, -1):
            block = OmegaConf.select(cfg, ".".join(parts[:cut]))
            if isinstance(block, DictConfig) and block.get("_target_") == "decpomdp.search.PlannerConfig":
                setting = ".".join(parts[cut:])
                planner = instantiate(block)
                if setting in planner.ignored():
                    raise ValueError(
                        f"{key}: the planner {'.'.join(parts[:cut])} (phases {list(planner.phases)}, "
                        f"ce_result {planner.ce_result!r}) ignores {setting}; set a key it reads"
                    )
                break


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
