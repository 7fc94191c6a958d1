"""The package graph: arrows point one way, and no module circles back (see docs/architecture.md).

Checked statically on every module's imports, including imports inside functions and under
``TYPE_CHECKING`` (a function-local import hides an arrow, it does not remove it):

* ``hbni_infra`` imports nothing of the project;
* ``classifiers`` and ``hbni_pyro`` never import each other, and import only ``hbni_infra`` of the rest;
* ``decpomdp`` imports only ``hbni_infra``: it sees perception through its perception protocol;
* no two modules import each other, directly or through others (importing ``a.b.c`` from outside ``a.b``
  runs ``a.b``'s ``__init__`` too, so it counts as importing that package);
* no experiment entry point (the ``entry`` of a ``conf/experiment/*.yaml``) imports another.
"""

from __future__ import annotations

import ast
from pathlib import Path

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


def modules(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for the project's packages under ``root`` (a package is its ``__init__``)."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if "conf" in parts:  # experiments/conf: the configs, shipped inside the package
                continue
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def climbing_imports(root: Path) -> dict[str, list[str]]:
    """Per module, the project modules it imports that its package may not import."""
    bad = {}
    for name, path in modules(root).items():
        package = name.split(".")[0]
        wrong = sorted(n for n in _imports(path) if n.split(".")[0] not in ALLOWED[package] | {package})
        if wrong:
            bad[name] = wrong
    return bad


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the modules whose code importing it runs (the module, and the packages above it that the
    importer is not inside)."""
    mods = modules(root)

    def owner(name: str) -> str:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    graph = {}
    for name, path in mods.items():
        edges = set()
        for target in filter(None, map(owner, _imports(path))):
            parts = target.split(".")
            edges |= {
                ".".join(parts[:k])
                for k in range(1, len(parts) + 1)
                if ".".join(parts[:k]) in mods and not (name + ".").startswith(".".join(parts[:k]) + ".")
            }
        graph[name] = edges - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_packages_import_only_downwards():
    assert climbing_imports(ROOT) == {}


def test_no_module_imports_itself_through_others():
    assert cycles(import_graph(ROOT)) == []


def _plant(root: Path, files: dict[str, str]) -> Path:
    for name, text in {**{f"{p}/__init__.py": "" for p in PACKAGES}, **files}.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


def test_a_planted_function_local_import_that_climbs_a_layer_is_caught(tmp_path):
    root = _plant(tmp_path, {"decpomdp/policy.py": "def run():\n    from experiments.run import main\n"})
    assert climbing_imports(root) == {"decpomdp.policy": ["experiments.run", "experiments.run.main"]}


def test_a_planted_circle_hidden_in_a_function_or_type_checking_block_is_caught(tmp_path):
    root = _plant(
        tmp_path,
        {
            "hbni_pyro/a.py": "from hbni_pyro.b import g\n",
            "hbni_pyro/b.py": "def g():\n    from hbni_pyro.a import f\n",
            "decpomdp/search/__init__.py": "from decpomdp.search.x import y\n",
            "decpomdp/search/x.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from decpomdp.dp import z\n",
            "decpomdp/dp.py": "from decpomdp.search.other import w\n",
            "decpomdp/search/other.py": "",
        },
    )
    assert cycles(import_graph(root)) == [
        ["decpomdp.dp", "decpomdp.search", "decpomdp.search.x"],
        ["hbni_pyro.a", "hbni_pyro.b"],
    ]


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
