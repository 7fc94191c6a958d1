"""The README's sweeps: every job composes and passes its checks, the comment above says how many jobs it
launches, and a planner setting the chosen planner ignores is refused, naming the key."""

import itertools
import re
from pathlib import Path

import pytest

from experiments.schemas import build_settings, check_overrides, compose_config, compose_settings

ROOT = Path(__file__).resolve().parents[1]


def readme_sweeps() -> list[tuple[int, list[str]]]:
    """(jobs the comment announces, the command's overrides) of every ``-m`` command in the README's bash blocks."""
    out = []
    for block in re.findall(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S):
        lines = block.replace("\\\n", " ").splitlines()
        for previous, line in zip([""] + lines, lines):
            if "experiments.run -m " in line:
                announced = re.match(r"# (\d+) jobs?\b", previous)
                assert announced, f"the sweep {line!r} does not say how many jobs it launches"
                out.append((int(announced.group(1)), line.split("experiments.run -m ", 1)[1].split()))
    return out


def jobs(overrides: list[str]) -> list[list[str]]:
    """Every job of a sweep: the cartesian product of comma-separated values."""
    options = [
        [f"{key}={value}" for value in values.split(",")] for key, values in (o.split("=", 1) for o in overrides)
    ]
    return [list(job) for job in itertools.product(*options)]


def test_every_readme_sweep_composes_and_says_how_many_jobs_it_launches():
    sweeps = readme_sweeps()
    assert len(sweeps) >= 2
    for announced, overrides in sweeps:
        expanded = jobs(overrides)
        assert len(expanded) == announced, (overrides, len(expanded))
        for job in expanded:
            check_overrides(build_settings(compose_config(job)), job)


@pytest.mark.parametrize(
    "override, message",
    [
        (
            "warm_planner.ce_alpha=0.3",
            r"warm_planner.ce_alpha: experiment mission never reads it: the planner warm_planner \(phases \['ls'\], "
            r"ce_result 'duel'\) ignores ce_alpha",
        ),
        (
            "planner.ce_injection_until=0.9",
            "planner.ce_injection_until: experiment mission never reads it: the planner planner .* ignores",
        ),
    ],
)
def test_a_setting_the_planner_ignores_is_refused(override, message):
    settings = build_settings(compose_config(["experiment=mission", override]))
    with pytest.raises(ValueError, match=message):
        check_overrides(settings, [override])
    check_overrides(settings, ["planner.ce_alpha=0.3", "warm_planner.ls_patience=4", "mission.threshold=0.9"])


def test_gdice_ignores_local_search():
    settings = compose_settings(["experiment=package_delivery"])
    with pytest.raises(ValueError, match="planners.gdice.ls_candidates: .* ignores ls_candidates"):
        check_overrides(settings, ["planners.gdice.ls_candidates=10"])
