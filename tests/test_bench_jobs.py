"""``benchmarks/bench_jobs.py``: the older commit's clean clone, its environment choice, the timing of a run and the
side-by-side table."""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

from benchmarks import bench_jobs


def test_clone_checks_out_the_commit_and_nothing_else(tmp_path):
    head = bench_jobs.short("HEAD")
    tree = bench_jobs.clone(head, tmp_path / "c")
    assert bench_jobs.short("HEAD") == head
    got = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    assert got.stdout.strip() == head
    assert not (tree / ".venv").exists() and (tree / "pyproject.toml").is_file()
    assert bench_jobs.same_dependencies(tree, tree)
    (tree / "constraints.txt").write_text((tree / "constraints.txt").read_text() + "\nnumpy<1\n")
    assert not bench_jobs.same_dependencies(tree, bench_jobs.ROOT)


def test_timed_counts_the_child_cpu_and_reports_a_failure(tmp_path):
    spin = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass"
    t = bench_jobs.timed([sys.executable, "-c", spin], tmp_path, {})
    assert t.cpu >= 0.3 and t.wall >= 0.3 and t.load >= 0 and t.status == 0
    with ThreadPoolExecutor(2) as pool:  # side by side, each run's CPU time is its own
        both = list(pool.map(lambda _: bench_jobs.timed([sys.executable, "-c", spin], tmp_path, {}), range(2)))
    assert all(0.3 <= b.cpu < 0.3 + t.cpu for b in both)
    log = tmp_path / "log"
    t = bench_jobs.timed([sys.executable, "-c", "import sys; print('no'); sys.exit(3)"], tmp_path, {}, log)
    assert t.status == 3 and log.read_text() == "no\n"


def test_table_gives_the_ratios_of_the_summed_repeats():
    T = bench_jobs.Timing
    runs = {
        "mission": {"old": [T(100, 200, 1), T(140, 200, 1)], "new": [T(60, 100, 1), T(60, 80, 1)]},
        "suite": {"old": [T(600, 900, 1)]},  # not run at the new commit: no row
    }
    lines = bench_jobs.table("old", "new", runs)
    assert len(lines) == 2 and lines[1].split()[0] == "mission"
    assert "0.50x" in lines[1] and "0.45x" in lines[1] and "4 min 00 s" in lines[1]


def test_matmul_rate_is_positive_and_leaves_the_thread_count():
    before = bench_jobs.torch.get_num_threads()
    assert bench_jobs.matmul_gflops(size=64, repeats=2) > 0
    assert bench_jobs.torch.get_num_threads() == before


def test_repeats_must_be_positive_and_the_kept_folder_new(tmp_path, capsys):
    with pytest.raises(SystemExit):
        bench_jobs.main(["--repeats", "0"])
    assert "--repeats" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench_jobs.main(["--keep", str(tmp_path)])
    assert "--keep" in capsys.readouterr().err
