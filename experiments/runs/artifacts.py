"""Saved artefacts of a run and loading a whole run back: ``load_run(run_dir)``.

An experiment saves each fitted object with :func:`save_artifact`, which writes the object's
own file and records it in ``run_dir/artifacts.json`` (name -> kind and relative path).
:func:`load_run` reads ``.hydra/config.yaml``, ``metrics.json`` and every recorded artefact.
Each artefact also loads on its own with its class's ``load(path)``.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from experiments.runs.outputs import write_json
from experiments.runs.paths import outputs_root
from experiments.runs.status import read_status

MANIFEST = "artifacts.json"

KINDS = ("FrameCalibration", "FrameClassifier", "HBNIPosterior", "JointController", "MacroObservationModel")
"""Classes whose objects a run can save; each writes one ``.safetensors`` file."""


def _loader(kind: str):
    if kind == "FrameCalibration":
        from hbni_pyro import FrameCalibration

        return FrameCalibration.load
    if kind == "HBNIPosterior":
        from hbni_pyro import HBNIPosterior

        return HBNIPosterior.load
    if kind == "MacroObservationModel":
        from hbni_pyro import MacroObservationModel

        return MacroObservationModel.load
    if kind == "JointController":
        from decpomdp import JointController

        return JointController.load
    if kind == "FrameClassifier":
        from classifiers import FrameClassifier

        return FrameClassifier.load
    raise ValueError(f"{MANIFEST}: unknown artefact kind {kind!r}, expected one of {list(KINDS)}")


def save_artifact(run_dir: str | os.PathLike, name: str, obj: Any) -> Path:
    """Save ``obj`` (anything with ``save(path)`` whose class is a known kind) as ``run_dir/<name>.<ext>``
    and record it in the run's manifest. Returns the written path."""
    kind = type(obj).__name__
    if kind not in KINDS:
        raise TypeError(f"obj: expected one of {list(KINDS)}, got {kind}")
    run_dir = Path(run_dir)
    rel = f"{name}.safetensors"
    path = obj.save(run_dir / rel)
    manifest = _read_manifest(run_dir) if (run_dir / MANIFEST).is_file() else {}
    manifest[name] = {"kind": kind, "path": rel}
    write_json(run_dir / MANIFEST, manifest)
    return Path(path)


def _read_manifest(run_dir: Path) -> dict[str, dict[str, str]]:
    try:
        manifest = json.loads((run_dir / MANIFEST).read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{run_dir / MANIFEST}: corrupt manifest ({exc})") from None
    if not isinstance(manifest, dict):
        raise ValueError(f"{run_dir / MANIFEST}: expected a JSON object of artefacts")
    return manifest


class Artifacts(Mapping):
    """A run's artefacts by name, each loaded from its file on first access (then kept).

    A damaged file raises when that artefact is asked for, naming the file; the others stay readable.
    ``recorded`` is False for a run that wrote no ``artifacts.json``.
    """

    def __init__(self, run_dir: Path, entries: dict[str, dict[str, str]], recorded: bool = True) -> None:
        self.run_dir, self.entries, self.recorded = run_dir, entries, recorded
        self._loaded: dict[str, Any] = {}

    def __getitem__(self, name: str) -> Any:
        if name not in self._loaded:
            entry = self.entries[name]
            path = self.run_dir / entry["path"]
            if not path.is_file():
                raise FileNotFoundError(f"run_dir: artefact {name!r} ({entry['kind']}) is missing: {str(path)!r}")
            try:
                self._loaded[name] = _loader(entry["kind"])(path)
            except (ValueError, OSError) as exc:
                raise ValueError(
                    f"run_dir: artefact {name!r} ({entry['kind']}) in {str(path)!r} cannot be read: {exc}"
                ) from None
        return self._loaded[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)


@dataclass
class Run:
    """A finished run: its composed config, metrics and fitted artefacts (also as attributes, loaded when first
    used)."""

    run_dir: Path
    cfg: DictConfig
    metrics: dict[str, Any]
    artifacts: Mapping[str, Any] = field(default_factory=dict)

    def __getattr__(self, name: str) -> Any:
        artifacts = self.__dict__.get("artifacts", {})
        if name in artifacts:
            return artifacts[name]
        if isinstance(artifacts, Artifacts) and not artifacts.recorded:
            raise AttributeError(f"run has no attribute {name!r}, and it recorded no artefacts (no {MANIFEST})")
        raise AttributeError(f"run has no artefact or attribute {name!r}; artefacts: {sorted(artifacts)}")

    def __dir__(self) -> list[str]:
        return sorted(set(super().__dir__()) | set(self.artifacts))


def load_run(run_dir: str | os.PathLike, allow_incomplete: bool = False) -> Run:
    """Load a run directory written by ``python -m experiments.run``.

    Returns a :class:`Run` whose artefacts load when first used, e.g. ``run.posterior.summary()`` or
    ``run.classifier.predict_proba(images)``; its config and metrics are read at once.

    Args:
        run_dir: the run's directory (Hydra's output directory).
        allow_incomplete: read what a failed or unfinished run left (its metrics may be empty);
            without it such a run is refused.

    Raises:
        FileNotFoundError: the directory or its ``.hydra/config.yaml`` is missing (a missing artefact raises
            when it is used).
        ValueError: the run failed or did not finish (unless ``allow_incomplete``), or the manifest is corrupt
            (a damaged artefact raises when it is used, naming its file).
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run_dir: no such run directory {str(run_dir)!r}")
    cfg_path = run_dir / ".hydra" / "config.yaml"
    if not cfg_path.is_file():
        raise FileNotFoundError(f"run_dir: {str(run_dir)!r} is not a Hydra run directory (no .hydra/config.yaml)")
    metrics_path = run_dir / "metrics.json"
    if not allow_incomplete:
        _check_completed(run_dir, metrics_path)
    cfg = OmegaConf.load(cfg_path)
    metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
    recorded = (run_dir / MANIFEST).is_file()
    return Run(run_dir, cfg, metrics, Artifacts(run_dir, _read_manifest(run_dir) if recorded else {}, recorded))


def latest_run(name: str, root: str | os.PathLike | None = None) -> Path:
    """The newest completed run directory of experiment ``name`` under ``root/<name>/`` (default root: the
    project's ``outputs``, :func:`experiments.runs.paths.outputs_root`, from any working directory).

    Raises:
        FileNotFoundError: no completed run of ``name`` under ``root``.
    """
    root = outputs_root() if root is None else Path(root)
    runs = sorted(
        p for p in (root / name).glob("*") if p.is_dir() and (read_status(p) or {}).get("status") == "completed"
    )
    if not runs:
        raise FileNotFoundError(
            f"name: no completed {name!r} run under {str(Path(root) / name)!r}; run `hbni-pyro experiment={name}` first"
        )
    return runs[-1]


def _check_completed(run_dir: Path, metrics_path: Path) -> None:
    """Raise ``ValueError`` unless the run completed (its status says so, or it wrote its metrics)."""
    status = read_status(run_dir)
    hint = "pass allow_incomplete=True to read what it left"
    if status is not None and status["status"] == "failed":
        raise ValueError(
            f"run_dir: the run in {str(run_dir)!r} failed ({status.get('error', 'no error recorded')}); {hint}"
        )
    if (status is not None and status["status"] != "completed") or not metrics_path.is_file():
        raise ValueError(f"run_dir: the run in {str(run_dir)!r} did not finish (no metrics.json); {hint}")
