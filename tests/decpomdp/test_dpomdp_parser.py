"""The .dpomdp loader: every form example.dpomdp documents (against the dense parser this package used
before), the shipped problems (plain and gzipped), compact tables, and malformed or hostile files."""

import gzip
import re

import numpy as np
import pytest

from decpomdp.dpomdp import (
    PROBLEM_DIR,
    DPOMDPSyntaxError,
    load_dpomdp,
    load_problem,
    parse_dpomdp,
    problem_names,
    problem_path,
)

BENCH = PROBLEM_DIR  # the shipped problems (other test modules import this name)
REFERENCE = np.load(__import__("pathlib").Path(__file__).parent / "data" / "parser_reference.npz")

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
    trans = m.transition.toarray()
    np.testing.assert_allclose(trans[0], [[0.5, 0.5], [0.5, 0.5]])  # uniform matrix
    np.testing.assert_allclose(trans[1], np.eye(2))  # identity
    np.testing.assert_allclose(trans[2], [[0.3, 0.7], [0.5, 0.5]])  # row form with wildcard agent
    np.testing.assert_allclose(trans[3], [[0.3, 0.7], [0.6, 0.4]])  # joint index + single entries
    for ja in (0, 1):
        np.testing.assert_allclose(m.observation[ja], [[0.25] * 4, [0.1, 0.2, 0.3, 0.4]])
    np.testing.assert_allclose(m.observation[2], [[0.5, 0.5, 0, 0], [0, 0, 0.5, 0.5]])  # matrix form
    np.testing.assert_allclose(m.observation[3], [[0, 0.5, 0.25, 0.25]] * 2)  # names, indices, '*' in jo
    expected = np.full((4, 2, 2, 4), -1.0)
    expected[0, 1] = 5.0
    expected[3, 0, 1] = [1, 2, 3, 4]
    expected[3, 1] = [[10, 11, 12, 13], [20, 21, 22, 23]]
    np.testing.assert_allclose(np.broadcast_to(m.reward, expected.shape), expected)
    r_exp = m.expected_reward()
    assert r_exp[3, 1] == pytest.approx(
        0.6 * np.dot([0, 0.5, 0.25, 0.25], [10, 11, 12, 13]) + 0.4 * np.dot([0, 0.5, 0.25, 0.25], [20, 21, 22, 23])
    )


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


def test_shipped_problems_load_plain_and_gzipped():
    shapes = {
        "dectiger": (2, 3, 2),
        "broadcastChannel": (4, 2, 2),
        "recycling": (4, 3, 2),
        "GridSmall": (16, 5, 2),
        "oneDoor_2_7_0.20_0.00_0_2": (65, 4, 2),
        "fireFighting_2_4_3": (2025, 4, 2),
    }
    assert set(shapes) | {"example"} == set(problem_names())
    for name, (s, a, o) in shapes.items():
        m = load_problem(name)
        assert m.transition.shape == (a * a, s, s) and m.observation.shape == (a * a, s, o * o)
        np.testing.assert_allclose(m.transition.row_sums(), 1.0)
        np.testing.assert_allclose(m.observation.sum(-1), 1.0)
    assert problem_path("fireFighting_2_4_3").name.endswith(".dpomdp.gz")
    assert problem_path("dectiger.dpomdp") == problem_path("dectiger") == BENCH / "dectiger.dpomdp"
    with pytest.raises(KeyError, match="no shipped problem 'nope'.*dectiger"):
        problem_path("nope")
    with pytest.raises(TypeError, match="name"):
        problem_path(3)
    tiger = load_problem("dectiger")
    np.testing.assert_allclose(tiger.observation[0, 0], [0.7225, 0.1275, 0.1275, 0.0225])
    np.testing.assert_allclose(tiger.expected_reward()[:, 0], [-2, -101, 9, -101, -50, -100, 9, -100, 20])
    assert (BENCH / "README.md").is_file() and "GNU GENERAL PUBLIC LICENSE" in (BENCH / "COPYING").read_text()


def test_compact_tables_of_the_large_problems():
    fire = load_problem("fireFighting_2_4_3")
    assert fire.reward.shape == (1, 1, 2025, 1)  # the file's rewards depend on the next state only
    assert fire.transition.nnz == 179_800 and fire.transition.indices.dtype == np.int64
    door = load_problem("oneDoor_2_7_0.20_0.00_0_2")
    assert door.reward.shape == (1, 65, 1, 1)  # ... on the state only
    # the expected reward over sparse rows equals the dense einsum
    dense_t = door.transition.toarray()
    full_r = np.broadcast_to(door.reward, dense_t.shape + (door.observation.shape[-1],))
    np.testing.assert_allclose(
        door.expected_reward(), np.einsum("ast,atj,astj->as", dense_t, door.observation, full_r), atol=1e-12
    )


@pytest.mark.parametrize("seed", range(60))
def test_synthetic_files_match_the_dense_parser(seed):
    """Random files mixing every T/O/R form with overwrites (see dpomdp_synthetic.py) give the tables that
    the dense parser of commit 0aad4c6 gave."""
    m = parse_dpomdp(str(REFERENCE[f"text_{seed}"]), check_probabilities=False)
    np.testing.assert_array_equal(m.start, REFERENCE[f"start_{seed}"])
    np.testing.assert_array_equal(m.transition.toarray(), REFERENCE[f"transition_{seed}"])
    np.testing.assert_array_equal(m.observation, REFERENCE[f"observation_{seed}"])
    full = REFERENCE[f"reward_{seed}"]
    np.testing.assert_array_equal(np.broadcast_to(m.reward, full.shape), full)


@pytest.mark.parametrize(
    "name", ["dectiger", "broadcastChannel", "recycling", "GridSmall", "oneDoor_2_7_0.20_0.00_0_2"]
)
def test_shipped_files_match_the_dense_parser(name):
    m = load_problem(name)
    np.testing.assert_allclose(m.transition.toarray(), REFERENCE[f"transition_{name}"], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(m.observation, REFERENCE[f"observation_{name}"])
    np.testing.assert_array_equal(m.start, REFERENCE[f"start_{name}"])
    full = REFERENCE[f"reward_{name}"]
    np.testing.assert_array_equal(np.broadcast_to(m.reward, full.shape), full)
    np.testing.assert_allclose(m.expected_reward(), REFERENCE[f"expected_reward_{name}"], rtol=0, atol=1e-12)


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
        (
            "R: 3 : s1 :\n10 11 12 13\n20 21 22 23",
            "R: 3 : s1 :\n10 11 12 13\nR: 0 : s0 : * : * : 1",
            "R: 0 : s0",
            "expected 8 numbers",
        ),
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


def test_unspecified_rows_and_truncated_files(tmp_path):
    text = HEADER + "O: * :\nuniform\n"
    with pytest.raises(DPOMDPSyntaxError, match="never specified") as info:
        parse_dpomdp(text)
    assert info.value.lineno == len(text.splitlines())
    with pytest.raises(DPOMDPSyntaxError, match=re.escape("unexpected end of file")):
        parse_dpomdp(HEADER.split("observations")[0])
    with pytest.raises(TypeError, match="text"):
        parse_dpomdp(b"agents: 2")
    with pytest.raises(FileNotFoundError, match="path"):
        load_dpomdp(tmp_path / "missing.dpomdp")


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf", "NaN", "1e999"])
@pytest.mark.parametrize(
    "old, new, needle",
    [
        ("T: 3 : s1 : s0 : 0.6", "T: 3 : s1 : s0 : {bad}", "T: 3 : s1 : s0"),  # single entry
        ("T: b * : s0 :\n0.3 0.7", "T: b * : s0 :\n0.3 {bad}", "0.3 {bad}"),  # row
        ("R: 3 : s1 :\n10 11 12 13\n20 21 22 23", "R: 3 : s1 :\n10 11 12 13\n20 {bad} 22 23", "20 {bad}"),  # matrix
        ("R: * : * : * : * : -1", "R: * : * : * : * : {bad}", "R: * : * : * : *"),
        ("O: b 1 : * : y * : 0.25", "O: b 1 : * : y * : {bad}", "O: b 1 : * : y *"),
        ("0.25 0.75", "0.25 {bad}", "0.25 {bad}"),  # start
        ("discount: 0.95", "discount: {bad}", "discount"),
    ],
)
def test_non_finite_numbers_are_rejected_with_their_line(bad, old, new, needle):
    text = GOOD.replace(old, new.format(bad=bad))
    assert text != GOOD
    with pytest.raises(DPOMDPSyntaxError, match="expected a finite number|expected a number") as info:
        parse_dpomdp(text)
    assert info.value.lineno == lineno_of(text, needle.format(bad=bad))


@pytest.mark.parametrize(
    "header, line, needed",
    [
        ("agents: 2\ndiscount: 1\nvalues: reward\nstates: 100000000\n", 4, r"100000000 states need \d+ bytes"),
        (
            "agents: 2\ndiscount: 1\nvalues: reward\nstates: 100000\nstart: uniform\nactions:\n100\n100\n",
            8,
            r"100000 states, 10000 joint actions and 1 joint observations need \d+ bytes",
        ),
        (
            (
                "agents: 2\ndiscount: 1\nvalues: reward\nstates: 3000\nstart: uniform\nactions:\n30\n30\n"
                "observations:\n30\n30\n"
            ),
            11,
            r"3000 states, 900 joint actions and 900 joint observations need",
        ),
        (
            "agents: 2\ndiscount: 1\nvalues: reward\nstates: 3\nstart: uniform\nactions:\n1000000000\n",
            7,
            r"1000000000 actions need",
        ),
    ],
)
def test_declared_sizes_above_the_memory_budget_are_rejected_before_allocation(header, line, needed):
    """A few bytes of header must not allocate gigabytes: the error names the line and the bytes needed."""
    text = header + "observations:\n2\n2\nT: * :\nuniform\n"
    with pytest.raises(DPOMDPSyntaxError, match=needed + r".*above the memory budget") as info:
        parse_dpomdp(text)
    assert info.value.lineno == line


def test_entries_that_would_outgrow_the_budget_are_rejected():
    head = "agents: 2\ndiscount: 1\nvalues: reward\nstates: 2000\nstart: uniform\nactions:\n2\n2\nobservations:\n1\n1\n"
    with pytest.raises(DPOMDPSyntaxError, match="transition entries need .* above the memory budget") as info:
        parse_dpomdp(head + "T: * :\nuniform\n", memory_budget=200_000_000)  # 16 M dense entries
    assert info.value.lineno == 12
    # a reward distinguishing (s, s') on 2000 states needs a (1, 2000, 2000, 1) table: 32 MB
    text = head + "T: * :\nidentity\nO: * :\nuniform\nR: * : 5 : 7 : * : 1\n"
    with pytest.raises(DPOMDPSyntaxError, match=r"reward table of shape \(1, 2000, 2000, 1\)") as info:
        parse_dpomdp(text, memory_budget=20_000_000)
    assert info.value.lineno == 16
    assert parse_dpomdp(text).reward.shape == (1, 2000, 2000, 1)  # fine under the default budget
    with pytest.raises(ValueError, match="memory_budget"):
        parse_dpomdp(text, memory_budget=0)


def test_binary_and_non_utf8_files_name_the_file(tmp_path):
    binary = tmp_path / "garbage.dpomdp"
    binary.write_bytes(bytes(range(256)) * 40)
    with pytest.raises(DPOMDPSyntaxError, match="garbage.dpomdp: not UTF-8 text"):
        load_dpomdp(binary)
    latin = tmp_path / "latin.dpomdp"
    latin.write_bytes((HEADER + BODY).replace("# comment", "# caf\xe9 comment").encode("latin-1"))
    with pytest.raises(DPOMDPSyntaxError, match=r"latin.dpomdp: not UTF-8 text \(byte 0xe9") as info:
        load_dpomdp(latin)
    assert info.value.lineno == len(HEADER.splitlines()) + 1
    nul = tmp_path / "nul.dpomdp"
    nul.write_bytes((HEADER + "T: * :\x00\n").encode())
    with pytest.raises(DPOMDPSyntaxError, match="nul.dpomdp: binary data") as info:
        load_dpomdp(nul)
    assert info.value.lineno == len(HEADER.splitlines()) + 1


def test_gzipped_files_load_directly_and_bad_ones_fail_cleanly(tmp_path):
    plain = problem_path("broadcastChannel").read_bytes()
    packed = tmp_path / "broadcast.dpomdp.gz"
    packed.write_bytes(gzip.compress(plain))
    a, b = load_dpomdp(packed), load_problem("broadcastChannel")
    np.testing.assert_array_equal(a.transition.toarray(), b.transition.toarray())
    np.testing.assert_array_equal(a.reward, b.reward)
    truncated = tmp_path / "truncated.dpomdp.gz"
    truncated.write_bytes(gzip.compress(plain)[:200])
    with pytest.raises(DPOMDPSyntaxError, match="truncated.dpomdp.gz: not a valid gzip file"):
        load_dpomdp(truncated)
    bomb = tmp_path / "bomb.dpomdp.gz"  # 50 MB of zeros in 50 KB
    bomb.write_bytes(gzip.compress(b"0" * 50_000_000))
    with pytest.raises(DPOMDPSyntaxError, match="bomb.dpomdp.gz: the file holds more than the memory budget"):
        load_dpomdp(bomb, memory_budget=10_000_000)


def test_mutated_files_raise_only_syntax_errors():
    """Seeded random edits of a valid file (deleted, duplicated or swapped lines, replaced tokens, injected
    characters): each either parses or raises DPOMDPSyntaxError naming a line, never another exception."""
    import random

    rng = random.Random(0)
    tokens = ["*", ":", "0", "9", "-1", "1e9", "nan", "uniform", "identity", "s0", "zz", "²", "T:", "R:", "\x00", "é"]
    lines = GOOD.splitlines()
    for _ in range(400):
        edit = list(lines)
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(len(edit))
            kind = rng.randrange(4)
            if kind == 0:
                del edit[i]
            elif kind == 1:
                edit.insert(i, edit[rng.randrange(len(edit))])
            elif kind == 2:
                toks = edit[i].split(" ")
                toks[rng.randrange(len(toks))] = rng.choice(tokens)
                edit[i] = " ".join(toks)
            else:
                pos = rng.randrange(len(edit[i]) + 1)
                edit[i] = edit[i][:pos] + rng.choice(tokens) + edit[i][pos:]
        text = "\n".join(edit) + "\n"
        try:
            parse_dpomdp(text)
        except DPOMDPSyntaxError as exc:
            assert 1 <= exc.lineno <= len(text.splitlines()) + 1, (exc, text)


def test_a_folder_is_not_a_problem_file(tmp_path):
    with pytest.raises(IsADirectoryError, match="is a folder, expected a .dpomdp file"):
        load_dpomdp(tmp_path)


def test_more_agents_than_action_lists_says_so():
    text = (PROBLEM_DIR / "dectiger.dpomdp").read_text().replace("agents: 2", "agents: 100000", 1)
    with pytest.raises(
        DPOMDPSyntaxError,
        match=r"actions: expected one list per agent \(100000 agents declared by "
        r"'agents:'\), found 2 before 'observations'",
    ):
        parse_dpomdp(text)
