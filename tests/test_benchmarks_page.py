"""``benchmarks/page.py``: the generated benchmarks page keeps the sections it does not rerun and names the rest."""

from __future__ import annotations

import importlib
import re

import pytest

from benchmarks import page


def test_every_benchmark_has_one_section_in_order():
    found = re.findall(r"<!-- bench:(\w+) -->", page.PAGE.read_text())
    assert found == page.benchmarks()


def test_write_keeps_runs_and_marks_the_rest_pending(tmp_path, monkeypatch):
    monkeypatch.setattr(page, "PAGE", tmp_path / "benchmarks.md")
    name = page.benchmarks()[0]
    ran = page.section(name, [([], "rate 1.0x")], "a machine", "2000-01-01")
    page.write({name: ran})
    kept = page.sections(page.PAGE.read_text())
    assert kept[name] == ran
    others = [n for n in page.benchmarks() if n != name]
    assert all(f"python -m benchmarks.page {n}`" in kept[n] for n in others)
    page.write(kept)  # a second rebuild changes nothing
    assert page.sections(page.PAGE.read_text()) == kept


def test_unknown_names_are_refused(monkeypatch, capsys):
    monkeypatch.setattr("sys.argv", ["page", "bench_nope"])
    with pytest.raises(SystemExit):
        page.main()
    assert "bench_nope" in capsys.readouterr().err


@pytest.mark.parametrize("name", sorted(p.stem for p in (page.ROOT / "benchmarks").glob("bench_*.py")))
def test_every_benchmark_imports_and_parses_its_arguments(name, monkeypatch, capsys):
    """Each benchmark imports and parses its arguments (``--help``); what it does past that shows when it runs."""
    module = importlib.import_module(f"benchmarks.{name}")
    monkeypatch.setattr("sys.argv", [name, "--help"])
    with pytest.raises(SystemExit) as info:
        module.main()
    assert info.value.code == 0 and capsys.readouterr().out.startswith("usage:")
