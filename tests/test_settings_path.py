"""One path for settings: the entry points compose the config, below them code reads typed settings only.

Checked statically on every module of ``experiments`` (docs/architecture.md):

* the raw config (a name ``cfg``, or one annotated ``DictConfig``/``ListConfig``) is read (``cfg.x``, ``cfg[...]``)
  only in the entry points: the modules Hydra hands the composed config to (the ``@hydra.main`` of
  :mod:`experiments.run` and the callbacks ``conf/config.yaml`` registers), which build the typed settings once
  (:func:`experiments.schemas.build_settings`);
* no function takes both a raw config and typed settings (a schema of :mod:`experiments.schemas`, or a
  ``*Settings`` record built from one).
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
RAW = {"DictConfig", "ListConfig"}


def _experiment_modules(root: Path) -> dict[str, Path]:
    """``experiments/...`` relative path -> file, the package's Python modules (its ``conf`` link aside)."""
    return {
        str(path.relative_to(root)): path
        for path in sorted((root / "experiments").rglob("*.py"))
        if "conf" not in path.relative_to(root).parts
    }


def entry_points(root: Path) -> set[str]:
    """The modules Hydra hands the composed config to: those with a ``@hydra.main`` function and those of the
    callbacks ``conf/config.yaml`` registers."""
    out = set()
    for rel, path in _experiment_modules(root).items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and any("hydra.main" in ast.unparse(d) for d in node.decorator_list):
                out.add(rel)
    callbacks = yaml.safe_load((root / "conf" / "config.yaml").read_text())["hydra"]["callbacks"]
    for callback in callbacks.values():
        module = callback["_target_"].rsplit(".", 1)[0]
        out.add(module.replace(".", "/") + ".py")
    return out


def _annotation_names(annotation: ast.expr | None) -> set[str]:
    """The names an annotation mentions (``DictConfig | None`` -> {DictConfig}; strings are parsed)."""
    if annotation is None:
        return set()
    if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
        annotation = ast.parse(annotation.value, mode="eval").body
    return {n.id for n in ast.walk(annotation) if isinstance(n, ast.Name)} | {
        n.attr for n in ast.walk(annotation) if isinstance(n, ast.Attribute)
    }


def _raw_names(tree: ast.AST) -> set[str]:
    """Names bound to a raw config in a module: ``cfg``, and every parameter or variable annotated as one."""
    names = {"cfg"}
    for node in ast.walk(tree):
        if isinstance(node, ast.arg) and _annotation_names(node.annotation) & RAW:
            names.add(node.arg)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if _annotation_names(node.annotation) & RAW:
                names.add(node.target.id)
    return names


def raw_config_reads(root: Path) -> dict[str, list[str]]:
    """Per module outside the entry points, the reads of a raw config it makes (``line: code``)."""
    allowed = entry_points(root)
    out = {}
    for rel, path in _experiment_modules(root).items():
        if rel in allowed:
            continue
        tree = ast.parse(path.read_text())
        raw = _raw_names(tree)
        reads = sorted(
            {
                f"{node.lineno}: {ast.unparse(node)}"
                for node in ast.walk(tree)
                if isinstance(node, (ast.Attribute, ast.Subscript))
                and isinstance(node.value, ast.Name)
                and node.value.id in raw
            },
            key=lambda s: int(s.split(":")[0]),
        )
        if reads:
            out[rel] = reads
    return out


def settings_types(root: Path) -> set[str]:
    """Names of typed settings: the classes and generated blocks of ``experiments/schemas``, and ``*Settings``
    records anywhere in ``experiments``."""
    out = set()
    for rel, path in _experiment_modules(root).items():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and (
                rel.startswith("experiments/schemas/") or node.name.endswith("Settings")
            ):
                out.add(node.name)
            elif rel.startswith("experiments/schemas/") and isinstance(node, ast.Assign):
                if isinstance(node.value, ast.Call) and ast.unparse(node.value.func).endswith("target_schema"):
                    out |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return out


def mixed_signatures(root: Path) -> dict[str, list[str]]:
    """Per module, the functions that take both a raw config and typed settings."""
    typed = settings_types(root)
    out = {}
    for rel, path in _experiment_modules(root).items():
        found = []
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            args = [*node.args.posonlyargs, *node.args.args, *node.args.kwonlyargs]
            raw = [a.arg for a in args if a.arg == "cfg" or _annotation_names(a.annotation) & RAW]
            settings = [a.arg for a in args if _annotation_names(a.annotation) & typed]
            if raw and settings:
                found.append(f"{node.lineno}: {node.name}({', '.join(raw + settings)})")
        if found:
            out[rel] = found
    return out


def test_the_entry_points_are_the_modules_hydra_calls():
    assert entry_points(ROOT) == {"experiments/run.py", "experiments/sweep.py", "experiments/reports/sweep_report.py"}


def test_no_raw_config_is_read_below_the_entry_points():
    assert raw_config_reads(ROOT) == {}


def test_no_function_takes_both_a_raw_config_and_typed_settings():
    assert {"Mission", "HBNIBlock", "PlannerBlock", "Settings"} <= settings_types(ROOT)
    assert mixed_signatures(ROOT) == {}


def _copy(tmp_path: Path) -> Path:
    """A copy of the tree the checks read (the ``experiments`` package and ``conf/config.yaml``)."""
    shutil.copytree(
        ROOT / "experiments", tmp_path / "experiments", ignore=shutil.ignore_patterns("conf", "__pycache__")
    )
    (tmp_path / "conf").mkdir()
    shutil.copy(ROOT / "conf" / "config.yaml", tmp_path / "conf" / "config.yaml")
    return tmp_path


def test_a_planted_config_read_below_the_entry_point_is_caught(tmp_path):
    root = _copy(tmp_path)
    study = root / "experiments" / "studies" / "mission.py"
    study.write_text(study.read_text() + "\n\ndef threshold(cfg):\n    return float(cfg.mission.threshold)\n")
    step = root / "experiments" / "steps" / "noise.py"
    step.write_text(step.read_text() + "\n\ndef mode(hbni: DictConfig) -> str:\n    return hbni['filter'].mode\n")
    reads = raw_config_reads(root)
    assert set(reads) == {"experiments/studies/mission.py", "experiments/steps/noise.py"}
    assert reads["experiments/studies/mission.py"][-1].endswith("cfg.mission")
    assert reads["experiments/steps/noise.py"][-1].endswith("hbni['filter']")


def test_a_planted_function_taking_both_a_config_and_settings_is_caught(tmp_path):
    root = _copy(tmp_path)
    step = root / "experiments" / "steps" / "planning.py"
    step.write_text(
        step.read_text() + "\n\ndef both(settings: 'BaselineStudy', planner: DictConfig | None) -> None:\n    pass\n"
    )
    found = mixed_signatures(root)
    assert list(found) == ["experiments/steps/planning.py"] and found["experiments/steps/planning.py"][0].endswith(
        "both(planner, settings)"
    )
