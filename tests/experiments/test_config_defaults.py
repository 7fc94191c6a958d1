"""Each default lives once: a config file sets only what differs from the Python default it would restate.

The dataclasses' and functions' defaults are the truth (``PlannerConfig``, ``HyperPrior``, ``DisasterRelief``,
``FrameClassifier``, ``hbni_pyro.fit``, ...): the experiments' schemas carry them into every composed config, so
a YAML value equal to one of them could only drift apart from it. Presets (``planner=gdice``, ``planner=mission``)
are compared with the defaults they build on, and an experiment's own overrides of a block with the preset it
composes there.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from hydra.core.config_store import ConfigStore
from hydra.utils import get_object
from omegaconf import OmegaConf

from experiments.schemas import register
from experiments.schemas.targets import signature_defaults

CONF = Path(__file__).resolve().parents[2] / "conf"
NAMED = {"hbni.fit": "hbni_pyro.fit", "hbni.filter": "hbni_pyro.HBNIFilter"}  # blocks typed without a _target_


def _plain(value: Any) -> Any:
    return [_plain(v) for v in value] if isinstance(value, (list, tuple)) else value


def restated(node: Any, defaults: dict[str, Any], path: str) -> list[str]:
    """``path.key=value`` for every key of ``node`` whose value equals its entry in ``defaults``."""
    return [f"{path}.{k}={v!r}".lstrip(".") for k, v in node.items() if k in defaults and _plain(defaults[k]) == v]


def targets(node: Any, path: str = "") -> list[tuple[str, dict, dict[str, Any]]]:
    """Every mapping in a YAML tree that names a target (``_target_`` or a :data:`NAMED` block), with its defaults."""
    found = []
    if isinstance(node, dict):
        target = node.get("_target_", NAMED.get(path.lstrip(".")))
        if isinstance(target, str):
            found.append((path, node, signature_defaults(get_object(target))))
        for key, value in node.items():
            found += targets(value, f"{path}.{key}" if path else key)
    return found


def _files() -> list[Path]:
    return sorted(p for p in CONF.rglob("*.yaml") if "hydra" not in p.parts)


@pytest.mark.parametrize("path", _files(), ids=lambda p: str(p.relative_to(CONF)))
def test_no_config_file_restates_a_python_default(path):
    tree = yaml.safe_load(path.read_text()) or {}
    if path.parent.name == "planner":  # every planner preset builds on PlannerConfig's defaults
        tree = {**tree, "_target_": "decpomdp.search.PlannerConfig"}
    if path.parent.name == "hbni":
        tree = {"hbni": tree}
    parent = parents(path)
    bad = []
    for where, node, defaults in targets(tree):
        above = OmegaConf.select(parent, where) if where else parent  # an experiment built on another sets over it
        overridden = {k for k in node if above is not None and k in above}
        bad += restated({k: v for k, v in node.items() if k not in overridden}, defaults, where)
    assert not bad, f"{path.relative_to(CONF)} restates Python defaults: {bad}"


def parents(path: Path) -> Any:
    """What the options of the same group in ``path``'s defaults list set before it (an experiment built on
    another), as one config."""
    tree = yaml.safe_load(path.read_text()) or {}
    above = OmegaConf.create()
    for entry in tree.get("defaults", []):
        if isinstance(entry, str) and entry != "_self_":
            sibling = path.parent / f"{entry}.yaml"
            own = {k: v for k, v in yaml.safe_load(sibling.read_text()).items() if k != "defaults"}
            above = OmegaConf.merge(above, parents(sibling), own)
    return above


def group_option(group: str, option: str) -> dict[str, Any]:
    """What ``group=option`` sets: its YAML file over the options its defaults list names, or its ConfigStore node."""
    path = CONF / group / f"{option}.yaml"
    if not path.exists():
        register()
        return OmegaConf.to_container(ConfigStore.instance().load(f"{group}/{option}.yaml").node)
    tree = yaml.safe_load(path.read_text()) or {}
    node: dict[str, Any] = {}
    for entry in tree.pop("defaults", []):
        node.update(group_option(group, entry) if entry != "_self_" else tree)
    return {**node, **tree}


@pytest.mark.parametrize("path", sorted((CONF / "experiment").glob("*.yaml")), ids=lambda p: p.stem)
def test_no_experiment_restates_the_preset_it_composes(path):
    """Values an experiment sets inside a block filled from a group (``- /planner@planners.gdice: gdice``) differ
    from that option's own and from its target's defaults."""
    tree = yaml.safe_load(path.read_text())
    bad = []
    for entry in tree.get("defaults", []):
        if not isinstance(entry, dict):
            continue
        ((key, option),) = entry.items()
        group, _, where = key.lstrip("/").partition("@")
        if group == "schema" or option is None:
            continue
        own = OmegaConf.select(OmegaConf.create(tree), where or group)
        if own is None:
            continue
        preset = group_option(group, option)
        target = preset.get("_target_", NAMED.get(group))
        defaults = signature_defaults(get_object(target)) if target else {}
        bad += restated(OmegaConf.to_container(own), {**defaults, **preset}, where or group)
    assert not bad, f"{path.name} restates its presets: {bad}"
