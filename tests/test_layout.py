"""The package graph: arrows point one way, and no module circles back (see docs/architecture.md).

Checked statically on every module's imports, including imports inside functions and under
``TYPE_CHECKING`` (a function-local import hides an arrow, it does not remove it):

* ``hbni_infra`` imports nothing of the project;
* ``classifiers`` and ``hbni_pyro`` never import each other, and import only ``hbni_infra`` of the rest;
* ``decpomdp`` imports only ``hbni_infra``: it sees perception through its perception protocol;
* no two modules import each other, directly or through others (importing ``a.b.c`` from outside ``a.b``
  runs ``a.b``'s ``__init__`` too, so it counts as importing that package);
* no experiment entry point (the ``entry`` of a ``conf/experiment/*.yaml``) imports another;
* inside ``hbni_pyro`` and ``experiments``, rooms (sub-packages, and the few modules beside them) import only the
  rooms :data:`ROOM_ARROWS` lets them: the arrows of docs/architecture.md;
* ``hbni_pyro``'s root holds at most 5 modules, each of its rooms has an ``__all__``, and no noise model spans more
  than 3 modules of the package outside its room;
* no two modules share a file name unless they are the same part of sibling rooms (each noise model's ``kernel``,
  each domain's ``rules``).
"""

from __future__ import annotations

import ast
import shutil
from collections import Counter
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


# ---- rooms ------------------------------------------------------------------------------------------------------

ROOM_ARROWS: dict[str, set[str]] = {
    # hbni_pyro, bottom up: the outputs' checks, what every model is written in, the shared MH machinery, the models,
    # their posterior, the fitting driver, streams into decisions, diagnostics, the robot runtime; the package's
    # __init__ (its public surface) above them all
    "hbni_pyro.validation": set(),
    "hbni_pyro.distributions": {"hbni_pyro.validation"},
    "hbni_pyro.mcmc": {"hbni_pyro.validation", "hbni_pyro.distributions"},
    "hbni_pyro.models": {"hbni_pyro.validation", "hbni_pyro.distributions", "hbni_pyro.mcmc", "hbni_pyro.models.*"},
    # a noise model's room: the models' shared record, and no other model's room but the one it builds on
    "hbni_pyro.models.paper": {
        "hbni_pyro.validation",
        "hbni_pyro.distributions",
        "hbni_pyro.mcmc",
        "hbni_pyro.models.spec",
    },
    "hbni_pyro.models.confusion": {
        "hbni_pyro.validation",
        "hbni_pyro.distributions",
        "hbni_pyro.mcmc",
        "hbni_pyro.models.spec",
        "hbni_pyro.models.paper",
    },
    "hbni_pyro.models.sequence": {
        "hbni_pyro.validation",
        "hbni_pyro.distributions",
        "hbni_pyro.mcmc",
        "hbni_pyro.models.spec",
    },
    "hbni_pyro.posterior": {"hbni_pyro.validation", "hbni_pyro.distributions", "hbni_pyro.models"},
    "hbni_pyro.fit": {"hbni_pyro.validation", "hbni_pyro.distributions", "hbni_pyro.models", "hbni_pyro.posterior"},
    "hbni_pyro.filters": {"hbni_pyro.validation", "hbni_pyro.distributions", "hbni_pyro.models", "hbni_pyro.posterior"},
    "hbni_pyro.diagnostics": {
        "hbni_pyro.validation",
        "hbni_pyro.distributions",
        "hbni_pyro.models",
        "hbni_pyro.posterior",
        "hbni_pyro.fit",
        "hbni_pyro.filters",
    },
    "hbni_pyro.runtime": {"hbni_pyro.validation", "hbni_pyro.posterior", "hbni_pyro.filters"},
    "hbni_pyro": {"hbni_pyro.*"},
    # experiments, bottom up: run folders, then the typed settings and the reports, the shared steps, the entry
    # points; beside them the command, a sweep's guard and the live ROS node (which imports none of them)
    "experiments.runs": set(),
    "experiments.schemas": {"experiments.runs"},
    "experiments.reports": {"experiments.runs"},
    "experiments.steps": {"experiments.runs", "experiments.schemas", "experiments.reports"},
    "experiments.studies": {"experiments.runs", "experiments.schemas", "experiments.reports", "experiments.steps"},
    "experiments.sweep": {"experiments.runs", "experiments.schemas", "experiments.reports"},
    "experiments.run": {"experiments.runs", "experiments.schemas", "experiments.sweep"},
    "experiments.ros_node": set(),
    "experiments": {"experiments.runs"},
}
"""Room -> the rooms (or single modules; ``x.*``: every room below ``x``) it may import. A module's room is the
longest key that is the module or a package above it."""


def room_of(name: str) -> str | None:
    """The room of module ``name`` (``None``: a package without rooms)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        if ".".join(parts[:k]) in ROOM_ARROWS:
            return ".".join(parts[:k])
    return None


def _allowed(target: str, arrows: set[str]) -> bool:
    return any(
        target == a or target.startswith(a + ".") or (a.endswith(".*") and target.startswith(a[:-1])) for a in arrows
    )


def room_violations(root: Path) -> dict[str, list[str]]:
    """Per module of a package with rooms, the modules of its package it imports against :data:`ROOM_ARROWS`."""
    mods = modules(root)

    def owner(name: str) -> str:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name

    bad = {}
    for name, path in mods.items():
        room = room_of(name)
        if room is None:
            continue
        wrong = set()
        for target in filter(None, map(owner, _imports(path))):
            target_room = room_of(target)
            if target_room is None or target_room == room or target_room.split(".")[0] != room.split(".")[0]:
                continue
            if not (_allowed(target, ROOM_ARROWS[room]) or _allowed(target_room, ROOM_ARROWS[room])):
                wrong.add(target)
        if wrong:
            bad[name] = sorted(wrong)
    return bad


def test_rooms_import_only_the_rooms_below_them():
    assert room_violations(ROOT) == {}
    assert {room_of(m) for m in modules(ROOT) if m.split(".")[0] in ("hbni_pyro", "experiments")} <= set(ROOM_ARROWS)


def test_a_planted_import_crossing_rooms_the_wrong_way_is_caught(tmp_path):
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("conf", "__pycache__"))
    kernel = tmp_path / "hbni_pyro" / "models" / "paper" / "kernel.py"
    kernel.write_text(kernel.read_text() + "\n\ndef _plot():\n    from hbni_pyro.filters import make_filter\n")
    step = tmp_path / "experiments" / "steps" / "noise.py"
    step.write_text(step.read_text() + "\nfrom experiments.studies.mission import run\n")
    sequence = tmp_path / "hbni_pyro" / "models" / "sequence" / "steps.py"
    sequence.write_text(sequence.read_text() + "\nfrom hbni_pyro.models.confusion.steps import split_conc\n")
    assert room_violations(tmp_path) == {
        "experiments.steps.noise": ["experiments.studies.mission"],
        "hbni_pyro.models.paper.kernel": ["hbni_pyro.filters"],
        "hbni_pyro.models.sequence.steps": ["hbni_pyro.models.confusion.steps"],
    }


def test_the_package_root_holds_its_public_surface_fit_and_few_more():
    root = sorted(p.name for p in (ROOT / "hbni_pyro").glob("*.py"))
    assert root == ["__init__.py", "fit.py", "validation.py"] and len(root) <= 5


def test_every_room_of_hbni_pyro_has_an_all():
    rooms = [p for p in (ROOT / "hbni_pyro").rglob("__init__.py")]
    assert len(rooms) >= 11
    for init in rooms:
        names = [t.id for n in ast.parse(init.read_text()).body if isinstance(n, ast.Assign) for t in n.targets]
        assert "__all__" in names, init


def model_spans(root: Path) -> dict[str, list[str]]:
    """Per noise model's room, the modules of ``hbni_pyro`` outside it that import it."""
    mods = modules(root)
    rooms = sorted(p.parent.name for p in (root / "hbni_pyro" / "models").glob("*/__init__.py"))
    out = {}
    for model in rooms:
        prefix = f"hbni_pyro.models.{model}"
        out[model] = sorted(
            name
            for name, path in mods.items()
            if name.startswith("hbni_pyro")
            and name != prefix
            and not name.startswith(prefix + ".")
            and any(t == prefix or t.startswith(prefix + ".") for t in _imports(path))
        )
    return out


def test_no_noise_model_spans_more_than_three_modules_outside_its_room():
    spans = model_spans(ROOT)
    assert set(spans) == {"paper", "confusion", "sequence"}
    assert all(len(importers) <= 3 for importers in spans.values()), spans


SAME_PART = {"__init__"}
"""File names that mean the same thing wherever they are."""


def name_clashes(root: Path) -> dict[str, list[str]]:
    """File name -> modules of that name in different places, unless they are the same part of sibling rooms (files
    of one name in subfolders of one folder: each noise model's ``kernel.py``, each domain's ``rules.py``)."""
    paths = [p for package in PACKAGES for p in (root / package).rglob("*.py") if "conf" not in p.parts]
    names = Counter(p.name for p in paths)
    out = {}
    for name, count in names.items():
        if count < 2 or name.removesuffix(".py") in SAME_PART:
            continue
        where = sorted(str(p.relative_to(root)) for p in paths if p.name == name)
        if len({Path(w).parent.parent for w in where}) > 1:
            out[name] = where
    return out


def test_one_meaning_per_module_name():
    assert name_clashes(ROOT) == {}


def test_a_planted_module_name_with_another_meaning_is_caught(tmp_path):
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("conf", "__pycache__"))
    (tmp_path / "hbni_pyro" / "runtime" / "checks.py").write_text("")
    assert name_clashes(tmp_path) == {"checks.py": ["hbni_infra/checks.py", "hbni_pyro/runtime/checks.py"]}
