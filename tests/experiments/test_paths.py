"""One root for runs, sweeps and caches: the working directory (or HBNI_PYRO_ROOT), never the installed package."""

import json
import os
from pathlib import Path

from experiments import latest_run
from experiments.runs.paths import project_root
from experiments.schemas import build_settings, compose_config

ROOT = Path(__file__).resolve().parents[2]


def _compose(*overrides):
    return compose_config(overrides, return_hydra_config=True)


def test_defaults_resolve_against_the_working_directory(tmp_path, monkeypatch):
    monkeypatch.delenv("HBNI_PYRO_ROOT", raising=False)
    monkeypatch.chdir(tmp_path)
    here = tmp_path.resolve()
    assert project_root() == here
    cfg = _compose("experiment=mission")
    build_settings(cfg)
    assert cfg.paths.root == str(here) and cfg.mission.bank.cache_dir == str(here / ".cache" / "banks")
    assert cfg.hydra.run.dir.startswith(str(here / "outputs" / "mission"))
    assert cfg.hydra.sweep.dir.startswith(str(here / "multirun" / "mission"))
    assert _compose("experiment=noise_models").study.cache_dir == str(here / ".cache" / "noise_models")


def test_the_root_can_be_moved_and_latest_run_finds_its_runs_from_anywhere(tmp_path, monkeypatch):
    root = tmp_path / "project"
    run = root / "outputs" / "mission" / "2026-01-01_00-00-00"
    run.mkdir(parents=True)
    (run / "status.json").write_text(json.dumps({"status": "completed"}))
    monkeypatch.setenv("HBNI_PYRO_ROOT", str(root))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert latest_run("mission") == run and os.getcwd() == str(elsewhere)
    assert _compose("experiment=mission").paths.outputs == str(root / "outputs")


def test_help_lists_every_experiment_on_one_line(tmp_path):
    import subprocess
    import sys

    from experiments.run import help_text

    out = subprocess.run(
        [sys.executable, "-m", "experiments.run", "experiment=hbni_toy", "-h"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
        env={**os.environ, "HBNI_PYRO_ROOT": str(tmp_path)},
    ).stdout
    names = sorted(p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml"))
    listed = {line.split()[0] for line in out.splitlines() if line.startswith("  ") and line.split()}
    assert set(names) <= listed and len(out.splitlines()) < 30
    assert out == help_text() + "\n" and not any(tmp_path.iterdir())  # the help runs nothing and writes nothing
