"""``run_experiment``, the tests' way to start ``python -m experiments.run``: a forked run answers as a fresh
interpreter does (streams, exit status, errors), a timeout kills it, and a changed import-time setting starts a
fresh interpreter."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from experiment_runs import _changes_import_settings, run_experiment

from experiments.run import help_text

BAD = ["experiment=hbni_toy", "hbni.fit.num_chains=0"]


def test_a_forked_run_answers_as_a_fresh_interpreter(tmp_path, repo_root):
    fresh = subprocess.run(
        [sys.executable, "-m", "experiments.run", *BAD, f"hydra.run.dir={tmp_path / 'a'}"],
        cwd=repo_root,
        capture_output=True,
        text=True,
    )
    forked = run_experiment([*BAD, f"hydra.run.dir={tmp_path / 'b'}"], repo_root, check=False)
    assert forked.returncode == fresh.returncode == 2 and forked.stdout == fresh.stdout == ""
    assert forked.stderr == fresh.stderr.replace("'a'", "'b'").replace("/a", "/b")
    assert forked.stderr.startswith("config error: hbni.fit.num_chains:")
    with pytest.raises(subprocess.CalledProcessError) as info:
        run_experiment(BAD, repo_root)
    assert info.value.returncode == 2 and info.value.stderr == forked.stderr
    helped = run_experiment(["-h"], tmp_path)
    assert helped.stdout == help_text() + "\n" and not any(tmp_path.iterdir())  # run in tmp_path, writing nothing


def test_a_run_past_its_timeout_is_killed(tmp_path, repo_root):
    with pytest.raises(subprocess.TimeoutExpired):
        run_experiment(["experiment=mission", f"hydra.run.dir={tmp_path}"], repo_root, timeout=0.5)


def test_a_changed_import_setting_starts_a_fresh_interpreter():
    assert not _changes_import_settings(dict(os.environ))
    assert not _changes_import_settings({**os.environ, "HBNI_PYRO_ROOT": "/elsewhere"})
    assert _changes_import_settings({**os.environ, "NUMBA_CACHE_DIR": "/elsewhere"})
    assert _changes_import_settings({**os.environ, "OMP_NUM_THREADS": "7"})
