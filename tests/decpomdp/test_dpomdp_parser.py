"""The .dpomdp loader on every form example.dpomdp documents, the shared benchmarks, and malformed files."""

import re
from pathlib import Path

import numpy as np
import pytest

from decpomdp.dpomdp import DPOMDPSyntaxError, load_dpomdp, parse_dpomdp

BENCH = Path("/work/shared/benchmarks/dpomdp")
if not BENCH.is_dir():
    BENCH = Path(__file__).resolve().parents[3] / "shared" / "benchmarks" / "dpomdp"

HEADER = """agents: 2
discount: 0.95
values: reward
states: s0 s1
start:
0.25 0.75
actions:
a b
2
observations:
x y
2
"""

BODY = """# comment lines and blank lines are skipped

T: * :
uniform
T: a 1 :
identity
T: b * : s0 :
0.3 0.7
T: 3 : s1 : s0 : 0.6
T: 3 : s1 : s1 : 0.4
O: * :
uniform
O: a * : s1 :
0.1 0.2 0.3 0.4
O: b 0 :
0.5 0.5 0 0
0 0 0.5 0.5
O: b 1 : * : y * : 0.25
O: b 1 : * : x 1 : 0.5
O: b 1 : * : 0 0 : 0
R: * : * : * : * : -1
R: a 0 : s1 : * : * : 5
R: b 1 : s0 : s1 :
1 2 3 4
R: 3 : s1 :
10 11 12 13
20 21 22 23
"""


def test_every_entry_form():
    m = parse_dpomdp(HEADER + BODY)
    assert m.agent_names == ["0", "1"] and m.state_names == ["s0", "s1"]
    assert m.action_names == [["a", "b"], ["0", "1"]] and m.obs_names == [["x", "y"], ["0", "1"]]
    assert m.discount == 0.95
    np.testing.assert_allclose(m.start, [0.25, 0.75])
    # joint action index = a1 * 2 + a2 (first agent most significant)
    np.testing.assert_allclose(m.transition[0], [[0.5, 0.5], [0.5, 0.5]])  # uniform matrix
    np.testing.assert_allclose(m.transition[1], np.eye(2))  # identity
    np.testing.assert_allclose(m.transition[2], [[0.3, 0.7], [0.5, 0.5]])  # row form with wildcard agent
    np.testing.assert_allclose(m.transition[3], [[0.3, 0.7], [0.6, 0.4]])  # joint index + single entries
    for ja in (0, 1):
        np.testing.assert_allclose(m.observation[ja], [[0.25] * 4, [0.1, 0.2, 0.3, 0.4]])
    np.testing.assert_allclose(m.observation[2], [[0.5, 0.5, 0, 0], [0, 0, 0.5, 0.5]])  # matrix form
    np.testing.assert_allclose(m.observation[3], [[0, 0.5, 0.25, 0.25]] * 2)  # names, indices, '*' in jo
    expected = np.full((4, 2, 2, 4), -1.0)
    expected[0, 1] = 5.0
    expected[3, 0, 1] = [1, 2, 3, 4]
    expected[3, 1] = [[10, 11, 12, 13], [20, 21, 22, 23]]
    np.testing.assert_allclose(m.reward, expected)
    r_exp = m.expected_reward()
    assert r_exp[3, 1] == pytest.approx(0.6 * np.dot([0, 0.5, 0.25, 0.25], [10, 11, 12, 13])
                                         + 0.4 * np.dot([0, 0.5, 0.25, 0.25], [20, 21, 22, 23]))


@pytest.mark.parametrize(
    "start, expected",
    [
        ("start: uniform", [1 / 3] * 3),
        ("start:\nuniform", [1 / 3] * 3),
        ("start: s1", [0, 1, 0]),
        ("start: 2", [0, 0, 1]),
        ("start: 0.2 0.3 0.5", [0.2, 0.3, 0.5]),
        ("start:\n0.2 0.3 0.5", [0.2, 0.3, 0.5]),
        ("start include: s0 2", [0.5, 0, 0.5]),
        ("start exclude: s1", [0.5, 0, 0.5]),
    ],
)
def test_start_forms(start, expected):
    text = f"agents: ag-1 ag_2\ndiscount: 1\nvalues: cost\nstates: s0 s1 s2\n{start}\nactions:\n1\n1\nobservations:\n1\n1\n"
    text += "T: * :\nidentity\nO: * :\nuniform\nR: * : * : * : * : 2\n"
    m = parse_dpomdp(text)
    np.testing.assert_allclose(m.start, expected)
    assert m.agent_names == ["ag-1", "ag_2"]
    assert np.all(m.reward == -2.0)  # values: cost negates


def test_shared_benchmarks_load():
    shapes = {"dectiger": (2, 3, 2), "broadcastChannel": (4, 2, 2), "recycling": (4, 3, 2), "GridSmall": (16, 5, 2)}
    for name, (s, a, o) in shapes.items():
        m = load_dpomdp(BENCH / f"{name}.dpomdp")
        assert m.transition.shape == (a * a, s, s) and m.observation.shape == (a * a, s, o * o)
        np.testing.assert_allclose(m.transition.sum(-1), 1.0)
        np.testing.assert_allclose(m.observation.sum(-1), 1.0)
    tiger = load_dpomdp(BENCH / "dectiger.dpomdp")
    np.testing.assert_allclose(tiger.observation[0, 0], [0.7225, 0.1275, 0.1275, 0.0225])
    np.testing.assert_allclose(tiger.expected_reward()[:, 0], [-2, -101, 9, -101, -50, -100, 9, -100, 20])


def test_example_file_reports_its_out_of_range_action():
    # example.dpomdp is a syntax tour, not a valid model: its agent 2 has 2 actions but line 199 says "T: 1 2 :".
    lines = (BENCH / "example.dpomdp").read_text().splitlines()
    with pytest.raises(DPOMDPSyntaxError, match=r"^line 199: example.dpomdp: .*index 2 out of range") as info:
        load_dpomdp(BENCH / "example.dpomdp", check_probabilities=False)
    assert lines[info.value.lineno - 1].startswith("T: 1 2 :")


def lineno_of(text, needle):
    """The last line starting with ``needle``."""
    return max(i + 1 for i, line in enumerate(text.splitlines()) if line.startswith(needle))


GOOD = HEADER + BODY


@pytest.mark.parametrize(
    "old, new, needle, message",
    [
        ("agents: 2\ndiscount: 0.95", "discount: 0.95\nagents: 2", "discount", "expected 'agents:'"),
        ("values: reward", "values: money", "values", "reward' or 'cost"),
        ("T: b * : s0 :", "T: b * : s9 :", "T: b * : s9", "unknown state 's9'"),
        ("T: b * : s0 :\n0.3 0.7", "T: b * : s0 :\n0.3 0.6 0.1", "0.3 0.6 0.1", "expected 2 numbers"),
        ("T: b * : s0 :\n0.3 0.7", "T: b * : s0 :\n0.3 zero", "0.3 zero", "expected a number, got 'zero'"),
        ("T: b * : s0 :\n0.3 0.7", "T: b * : s0 :\n0.3 0.3", "0.3 0.3", "sums to 0.6"),
        ("T: 3 : s1 : s1 : 0.4", "T: 3 : s1 : s1 : -0.4", "T: 3 : s1 : s1", "must lie in \\[0, 1\\]"),
        ("T: a 1 :", "T: a 1 1 :", "T: a 1 1", "expected 1 or 2 components"),
        ("T: a 1 :", "T: a 5 :", "T: a 5", "index 5 out of range"),
        ("O: b 0 :\n0.5 0.5 0 0\n0 0 0.5 0.5", "O: b 0 :\nidentity", "identity", "square"),
        ("R: 3 : s1 :\n10 11 12 13\n20 21 22 23", "R: 3 : s1 :\n10 11 12 13\nR: 0 : s0 : * : * : 1", "R: 0 : s0",
         "expected 8 numbers"),
        ("R: a 0 : s1 : * : * : 5", "Q: a 0 : s1 : * : * : 5", "Q: a 0", "expected a 'T:', 'O:' or 'R:'"),
        ("R: a 0 : s1 : * : * : 5", "R: a 0 : s1 : * : * : 5 : 6 : 7", "R: a 0 :", "R: expected"),
    ],
)
def test_malformed_files_name_the_line(old, new, needle, message):
    text = GOOD.replace(old, new)
    assert text != GOOD
    with pytest.raises(DPOMDPSyntaxError, match=message) as info:
        parse_dpomdp(text)
    assert info.value.lineno == lineno_of(text, needle)
    assert str(info.value).startswith(f"line {info.value.lineno}:")


def test_unspecified_rows_and_truncated_files():
    text = HEADER + "O: * :\nuniform\n"
    with pytest.raises(DPOMDPSyntaxError, match="never specified") as info:
        parse_dpomdp(text)
    assert info.value.lineno == len(text.splitlines())
    with pytest.raises(DPOMDPSyntaxError, match=re.escape("unexpected end of file")):
        parse_dpomdp(HEADER.split("observations")[0])
    with pytest.raises(TypeError, match="text"):
        parse_dpomdp(b"agents: 2")
    with pytest.raises(FileNotFoundError, match="path"):
        load_dpomdp("/nonexistent/file.dpomdp")
