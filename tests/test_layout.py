"""The package graph: arrows point one way (see docs/architecture.md).

Checked statically on every module's imports (including imports inside functions):

* ``hbni_infra`` imports nothing of the project;
* ``classifiers`` and ``hbni_pyro`` never import each other, and import only ``hbni_infra`` of the rest;
* ``decpomdp`` imports only ``hbni_infra``: it sees perception through its perception protocol;
* no experiment entry point (the ``entry`` of a ``conf/experiment/*.yaml``) imports another.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hbni_infra", "hbni_pyro", "classifiers", "decpomdp", "experiments")
ALLOWED = {
    "hbni_infra": set(),
    "hbni_pyro": {"hbni_infra"},
    "classifiers": {"hbni_infra"},
    "decpomdp": {"hbni_infra"},
    "experiments": {"hbni_infra", "hbni_pyro", "classifiers", "decpomdp"},
}


def _imports(path: Path) -> set[str]:
    """Dotted names of the project's modules that ``path`` imports (absolute imports only)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {n for n in names if n.split(".")[0] in PACKAGES}


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", PACKAGES)
def test_packages_import_only_downwards(package):
    bad = {
        str(path.relative_to(ROOT)): sorted(
            n for n in _imports(path) if n.split(".")[0] not in ALLOWED[package] | {package}
        )
        for path in _modules(package)
    }
    assert not {k: v for k, v in bad.items() if v}


def _entry_modules() -> dict[str, str]:
    """Experiment name -> module of its entry point."""
    out = {}
    for cfg in sorted((ROOT / "conf" / "experiment").glob("*.yaml")):
        entry = yaml.safe_load(cfg.read_text()).get("entry")
        if entry:
            out[cfg.stem] = entry.rsplit(".", 1)[0]
    return out


def test_no_entry_point_imports_another():
    entries = set(_entry_modules().values())
    assert len(entries) >= 5
    offenders = {}
    for module in entries:
        path = ROOT / (module.replace(".", "/") + ".py")
        others = {n for n in _imports(path) for e in entries - {module} if n == e or n.startswith(e + ".")}
        if others:
            offenders[module] = sorted(others)
    assert not offenders
