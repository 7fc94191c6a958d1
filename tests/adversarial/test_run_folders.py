"""A run folder belongs to one run: a live run holds it, a completed or failed run's folder is refused unless
``run.overwrite=true``, a refused run changes nothing in it (byte for byte), sweeps follow the same rule, and
``latest_run`` skips damaged siblings and names them."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from experiment_runs import run_experiment

from experiments import latest_run, load_run
from experiments.runs.claim import LOCK, FolderTaken, claim, live_holder, previous_run

FIT = ["hbni.fit.num_chains=2", "hbni.fit.num_samples=30", "hbni.fit.warmup_steps=30", "progress=false"]
TOY = ["experiment=hbni_toy", *FIT]


def snapshot(folder: Path) -> dict[str, tuple[int, bytes]]:
    """Every file and folder under ``folder``: relative path -> (mode, bytes)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        out[str(path.relative_to(folder))] = (path.stat().st_mode, b"" if path.is_dir() else path.read_bytes())
    return out


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory, repo_root):
    """A completed hbni_toy run folder (copy it before using it)."""
    run_dir = tmp_path_factory.mktemp("completed") / "run"
    run_experiment([*TOY, f"hydra.run.dir={run_dir}"], repo_root)
    return run_dir


@pytest.mark.parametrize("experiment", ["hbni_toy", "stream"])
def test_a_run_into_a_completed_runs_folder_is_refused_and_changes_nothing(toy_run, tmp_path, repo_root, experiment):
    # a stream run once marked the completed run it was refused by failed: any experiment is refused before it starts
    folder = tmp_path / "run"
    shutil.copytree(toy_run, folder)
    before = snapshot(folder)
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "0.png"), np.zeros((32, 32, 3), np.uint8))
    args = [*TOY, "seed=1"] if experiment == "hbni_toy" else ["experiment=stream", f"stream.source={frames}"]
    env = {**os.environ, "HBNI_PYRO_ROOT": str(tmp_path)}
    proc = run_experiment([*args, f"hydra.run.dir={folder}"], repo_root, env=env, check=False)
    assert proc.returncode == 2 and proc.stdout == "", proc.stderr
    assert proc.stderr == (
        f"run folder error: {folder}: holds a completed run; set run.overwrite=true to replace it, or run into "
        "another folder (hydra.run.dir=..., or hydra.sweep.dir=... for a sweep)\n"
    )
    assert snapshot(folder) == before  # status.json, run.log, .hydra and the results as they were
    assert load_run(folder).metrics["outputs"] == 15


def test_a_failed_run_or_one_that_died_running_is_refused_too(toy_run, tmp_path, repo_root):
    for state, says in (("failed", "holds a failed run"), ("running", "holds a run that stopped without finishing")):
        folder = tmp_path / state
        shutil.copytree(toy_run, folder)
        (folder / "status.json").write_text(json.dumps({"status": state}))
        (folder / LOCK).write_text(json.dumps({"pid": 1, "host": "elsewhere", "since": "then", "command": "x"}))
        before = snapshot(folder)
        proc = run_experiment([*TOY, f"hydra.run.dir={folder}"], repo_root, check=False)
        assert proc.returncode == 2 and says in proc.stderr and "run.overwrite=true" in proc.stderr, proc.stderr
        assert snapshot(folder) == before


def test_overwrite_replaces_the_earlier_run_whole(toy_run, tmp_path, repo_root):
    folder = tmp_path / "run"
    shutil.copytree(toy_run, folder)
    (folder / "old_figure.png").write_bytes(b"a figure of the earlier run")
    run_experiment([*TOY, "seed=1", "run.overwrite=true", f"hydra.run.dir={folder}"], repo_root)
    assert not (folder / "old_figure.png").exists() and not (folder / LOCK).exists()
    log = (folder / "run.log").read_text()
    assert log.count("writing to") == 1 and "(seed 1)" in log  # the new run's log alone
    assert load_run(folder).cfg.seed == 1


def test_two_runs_started_together_one_runs_and_the_other_is_refused(tmp_path, repo_root):
    folder = tmp_path / "run"
    results: dict[int, subprocess.CompletedProcess] = {}

    def start(seed: int) -> None:
        results[seed] = run_experiment([*TOY, f"seed={seed}", f"hydra.run.dir={folder}"], repo_root, check=False)

    threads = [threading.Thread(target=start, args=(seed,)) for seed in (1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    codes = sorted(r.returncode for r in results.values())
    assert codes == [0, 2], {s: (r.returncode, r.stderr) for s, r in results.items()}
    winner = next(s for s, r in results.items() if r.returncode == 0)
    loser = results[3 - winner]
    # refused while the winner held the folder (naming it once its lock file does), or once it had completed there
    assert "in use by a live run (" in loser.stderr or "holds a completed run" in loser.stderr, loser.stderr
    log = (folder / "run.log").read_text()
    assert log.count("writing to") == 1 and f"(seed {winner})" in log
    assert load_run(folder).cfg.seed == winner and not (folder / LOCK).exists()


def test_a_folder_a_live_run_holds_is_refused_naming_the_run(tmp_path):
    folder = tmp_path / "run"
    held = claim(folder)
    try:
        assert live_holder(folder).startswith(f"run (pid {os.getpid()} on ")
        with pytest.raises(FolderTaken, match=rf"in use by a live run \(pid {os.getpid()} on .*\)"):
            claim(folder, overwrite=True)  # overwrite never takes a live run's folder
    finally:
        held.release()
    assert not (folder / LOCK).exists() and live_holder(folder) is None
    claim(folder).release()  # free again


def test_a_lock_left_by_a_killed_process_blocks_nothing(tmp_path):
    folder = tmp_path / "run"
    code = f"from experiments.runs.claim import claim; claim({str(folder)!r}); import os; os._exit(0)"
    subprocess.run([sys.executable, "-c", code], check=True)
    assert (folder / LOCK).is_file() and live_holder(folder) is None  # the kernel dropped the lock
    held = claim(folder)  # a folder with no earlier run: taken
    assert json.loads((folder / LOCK).read_text())["pid"] == os.getpid()
    held.release()


def test_overwrite_never_clears_the_working_directory(tmp_path, monkeypatch):
    (tmp_path / "status.json").write_text('{"status": "completed"}')
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="will not clear .* it holds the working directory"):
        claim(tmp_path, overwrite=True)
    assert (tmp_path / "status.json").is_file() and not (tmp_path / LOCK).exists()


def test_what_an_earlier_run_left_is_named(tmp_path):
    assert previous_run(tmp_path / "none") is None and previous_run(tmp_path) is None
    (tmp_path / "multirun.yaml").write_text("{}")
    (tmp_path / "0").mkdir()
    assert previous_run(tmp_path) == "an earlier sweep (1 job folders)"
    (tmp_path / "multirun.yaml").unlink()
    (tmp_path / ".hydra").mkdir()
    assert previous_run(tmp_path) == "an earlier run that wrote no status.json"
    (tmp_path / "status.json").write_bytes(b"\xff{")
    assert previous_run(tmp_path) == "an earlier run whose status.json cannot be read"


def test_a_sweep_into_an_earlier_sweeps_folder_is_refused_and_overwrite_replaces_it(tmp_path, repo_root):
    # an earlier sweep's folder as a sweep leaves it (tests/experiments/test_sweep_report.py runs one in worker
    # processes and checks that it leaves no lock file)
    sweep = tmp_path / "sweep"
    for job in ("0", "1", "2"):
        (sweep / job / ".hydra").mkdir(parents=True)
        (sweep / job / "status.json").write_text(json.dumps({"status": "completed"}))
    (sweep / "multirun.yaml").write_text("hydra: {}\n")
    (sweep / "report.md").write_text("# the earlier sweep\n")
    before = snapshot(sweep)
    args = ["-m", *TOY, f"hydra.sweep.dir={sweep}", "seed=5,6", "hydra.launcher.n_jobs=1"]  # jobs in the parent
    proc = run_experiment(args, repo_root, check=False)
    assert proc.returncode == 2 and proc.stderr == (
        f"run folder error: {sweep}: holds an earlier sweep (3 job folders); set run.overwrite=true to replace it, or "
        "run into another folder (hydra.run.dir=..., or hydra.sweep.dir=... for a sweep)\n"
    )
    assert snapshot(sweep) == before
    run_experiment([*args, "run.overwrite=true"], repo_root)
    jobs = sorted(p.name for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert jobs == ["0", "1"] and "seed=5" in (sweep / "0" / ".hydra" / "overrides.yaml").read_text()
    assert (sweep / "report.md").read_text().count("| completed |") == 2 and not list(sweep.rglob("*.lock"))


def test_latest_run_skips_damaged_siblings_and_names_them(tmp_path):
    for name, status in (("2026-01-01", "completed"), ("2026-01-02", "completed"), ("2026-01-03", "{not json")):
        (tmp_path / "mission" / name).mkdir(parents=True)
        (tmp_path / "mission" / name / "status.json").write_text(
            status if status.startswith("{") else json.dumps({"status": status})
        )
    (tmp_path / "mission" / "2026-01-04").mkdir()
    (tmp_path / "mission" / "2026-01-04" / "status.json").write_text('{"status": "exploded"}')
    with pytest.warns(UserWarning, match=r"skipped 2 run folder\(s\) .*2026-01-03.*2026-01-04"):
        assert latest_run("mission", tmp_path) == tmp_path / "mission" / "2026-01-02"
