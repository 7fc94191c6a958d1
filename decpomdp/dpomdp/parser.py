"""Parser for the MADP toolbox's ``.dpomdp`` text format.

Every form documented by ``example.dpomdp`` is read: the header (``agents``, ``discount``,
``values``, ``states``, ``start``, ``actions``, ``observations``, in that order, each once;
counts or name lists), the four ``start`` forms (a probability vector on the next line or the
same line, ``uniform``, one state by name or index, ``start include:`` / ``start exclude:``),
and ``T``/``O``/``R`` entries in single-number, row and matrix forms, with ``uniform`` and
``identity``, names or indices, ``*`` wildcards, joint actions/observations given by index or
by their per-agent components (indices, names or ``*``). Later entries overwrite earlier ones.
Joint indices put the first agent's component most significant. ``values: cost`` negates rewards.

Blank lines and lines starting with ``#`` are skipped. Any error raises :class:`DPOMDPSyntaxError`
(a ``ValueError``) whose message starts with ``line N:``.
"""

from __future__ import annotations

import itertools
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
_HEADER = ("agents", "discount", "values", "states", "start", "actions", "observations")
_PROB_TOL = 1e-6


class DPOMDPSyntaxError(ValueError):
    """A malformed ``.dpomdp`` file; ``lineno`` is the 1-based line of the problem."""

    def __init__(self, lineno: int, message: str) -> None:
        super().__init__(f"line {lineno}: {message}")
        self.lineno = lineno


@dataclass
class DPOMDPModel:
    """A tabular Dec-POMDP (numpy float64 tables).

    Attributes:
        agent_names, state_names: lists of names.
        action_names, obs_names: per agent, a list of names.
        discount: the file's discount (a caller may use another).
        start: (S,) initial state distribution.
        transition: (JA, S, S') ``P(s' | s, ja)``.
        observation: (JA, S', JO) ``P(jo | ja, s')``.
        reward: (JA, S, S', JO) reward (negated cost for ``values: cost``).
    """

    agent_names: list[str]
    state_names: list[str]
    action_names: list[list[str]]
    obs_names: list[list[str]]
    discount: float
    start: np.ndarray
    transition: np.ndarray
    observation: np.ndarray
    reward: np.ndarray

    @property
    def num_agents(self) -> int:
        return len(self.agent_names)

    @property
    def num_states(self) -> int:
        return len(self.state_names)

    def expected_reward(self) -> np.ndarray:
        """(JA, S) ``R(s, ja) = sum_{s', jo} T(s'|s, ja) O(jo|ja, s') R(s, ja, s', jo)``."""
        return np.einsum("ast,atj,astj->as", self.transition, self.observation, self.reward)


class _Lines:
    """Content lines (number, text) with comments and blank lines removed."""

    def __init__(self, text: str) -> None:
        self.items = [
            (i + 1, line.strip())
            for i, line in enumerate(text.splitlines())
            if line.strip() and not line.lstrip().startswith("#")
        ]
        self.pos = 0
        self.last = len(text.splitlines())

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[int, str]:
        if self.pos >= len(self.items):
            raise DPOMDPSyntaxError(self.last, f"unexpected end of file, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]


def _number(tok: str, lineno: int) -> float:
    try:
        return float(tok)
    except ValueError:
        raise DPOMDPSyntaxError(lineno, f"expected a number, got {tok!r}") from None


def _names(rest: str, lineno: int, what: str) -> list[str]:
    """A count (``3`` -> ['0', '1', '2'] as index names) or a list of identifiers."""
    toks = rest.split()
    if not toks:
        raise DPOMDPSyntaxError(lineno, f"expected a count or a list of {what} names")
    if len(toks) == 1 and toks[0].isdigit():
        n = int(toks[0])
        if n < 1:
            raise DPOMDPSyntaxError(lineno, f"expected at least one {what}, got {n}")
        return [str(i) for i in range(n)]
    for tok in toks:
        if not _IDENT.match(tok):
            raise DPOMDPSyntaxError(lineno, f"{tok!r} is not a valid {what} name (a letter then alphanumerics, '-', '_')")
    if len(set(toks)) != len(toks):
        raise DPOMDPSyntaxError(lineno, f"duplicate {what} names in {toks}")
    return toks


def _index(tok: str, names: list[str], lineno: int, what: str, wildcard: bool = True) -> list[int]:
    """Indices denoted by a name, an index, or ``*``."""
    if tok == "*" and wildcard:
        return list(range(len(names)))
    if tok.isdigit():
        i = int(tok)
        if i >= len(names):
            raise DPOMDPSyntaxError(lineno, f"{what} index {i} out of range (there are {len(names)})")
        return [i]
    if tok in names:
        return [names.index(tok)]
    raise DPOMDPSyntaxError(lineno, f"unknown {what} {tok!r} (known: {' '.join(names)})")


def _joint(spec: str, per_agent: list[list[str]], lineno: int, what: str) -> list[int]:
    """Joint indices for a joint action/observation spec: ``*``, a joint index, or one token per agent."""
    toks = spec.split()
    sizes = [len(n) for n in per_agent]
    total = int(np.prod(sizes))
    if len(toks) == 1 and len(per_agent) > 1:
        return _index(toks[0], [str(i) for i in range(total)], lineno, f"joint {what}")
    if len(toks) != len(per_agent):
        raise DPOMDPSyntaxError(lineno, f"joint {what} {spec.strip()!r}: expected 1 or {len(per_agent)} components")
    comps = [_index(tok, names, lineno, f"{what} of agent {a}") for a, (tok, names) in enumerate(zip(toks, per_agent))]
    strides = np.cumprod([1] + sizes[::-1][:-1])[::-1]
    return [int(np.dot(c, strides)) for c in itertools.product(*comps)]


def _read_numbers(lines: _Lines, count: int, lineno: int, what: str) -> tuple[np.ndarray, int]:
    """Read ``count`` numbers from the following lines (``uniform``/``identity`` handled by callers)."""
    values: list[float] = []
    last = lineno
    while len(values) < count:
        nxt = lines.peek()
        if nxt is None or re.match(r"^[TOR]\s*:", nxt[1]):
            raise DPOMDPSyntaxError(nxt[0] if nxt else lines.last, f"{what}: expected {count} numbers, got {len(values)}")
        last, text = lines.next(what)
        toks = text.split()
        if len(values) + len(toks) > count:
            raise DPOMDPSyntaxError(last, f"{what}: expected {count} numbers, got at least {len(values) + len(toks)}")
        values.extend(_number(tok, last) for tok in toks)
    return np.asarray(values, dtype=np.float64), last


def _special(lines: _Lines, shape: tuple[int, int], lineno: int, what: str, allow_identity: bool) -> tuple[np.ndarray, int]:
    """A matrix on the following lines: ``uniform``, ``identity`` or rows of numbers."""
    nxt = lines.peek()
    if nxt is not None and nxt[1] in ("uniform", "identity"):
        ln, word = lines.next(what)
        if word == "uniform":
            return np.full(shape, 1.0 / shape[1]), ln
        if not allow_identity or shape[0] != shape[1]:
            raise DPOMDPSyntaxError(ln, f"{what}: 'identity' needs a square matrix, this one is {shape[0]} x {shape[1]}")
        return np.eye(shape[0]), ln
    values, ln = _read_numbers(lines, shape[0] * shape[1], lineno, what)
    return values.reshape(shape), ln


def _row(lines: _Lines, n: int, lineno: int, what: str) -> tuple[np.ndarray, int]:
    nxt = lines.peek()
    if nxt is not None and nxt[1] == "uniform":
        ln, _ = lines.next(what)
        return np.full(n, 1.0 / n), ln
    return _read_numbers(lines, n, lineno, what)


def _header(lines: _Lines) -> dict:
    out: dict = {}
    for key in _HEADER:
        lineno, text = lines.next(f"'{key}:'")
        m = re.match(r"^(\w+)(\s+(include|exclude))?\s*:(.*)$", text)
        if not m or m.group(1) != key:
            raise DPOMDPSyntaxError(lineno, f"expected '{key}:' (header entries come in the order {', '.join(_HEADER)})")
        if m.group(3) and key != "start":
            raise DPOMDPSyntaxError(lineno, f"'{m.group(3)}' only applies to 'start'")
        rest = m.group(4).strip()
        if key == "agents":
            out["agents"] = _names(rest, lineno, "agent")
        elif key == "discount":
            out["discount"] = _number(rest, lineno)
            if not 0.0 <= out["discount"] <= 1.0:
                raise DPOMDPSyntaxError(lineno, f"discount must lie in [0, 1], got {out['discount']}")
        elif key == "values":
            if rest not in ("reward", "cost"):
                raise DPOMDPSyntaxError(lineno, f"values: expected 'reward' or 'cost', got {rest!r}")
            out["values"] = rest
        elif key == "states":
            out["states"] = _names(rest, lineno, "state")
        elif key == "start":
            out["start"] = _start(lines, lineno, m.group(3), rest, out["states"])
        else:
            n_agents = len(out["agents"])
            if rest:
                raise DPOMDPSyntaxError(lineno, f"{key}: the per-agent lists go on the following {n_agents} lines")
            what = key[:-1] if key == "actions" else "observation"
            out[key] = [_names(lines.next(f"{what}s of agent {a}")[1], lines.items[lines.pos - 1][0], what)
                        for a in range(n_agents)]
    return out


def _start(lines: _Lines, lineno: int, mode: str | None, rest: str, states: list[str]) -> np.ndarray:
    n = len(states)
    if mode:
        chosen = sorted({i for tok in rest.split() for i in _index(tok, states, lineno, "state", wildcard=False)})
        if not chosen:
            raise DPOMDPSyntaxError(lineno, f"start {mode}: expected a list of states")
        mask = np.zeros(n, dtype=bool)
        mask[chosen] = True
        mask = mask if mode == "include" else ~mask
        if not mask.any():
            raise DPOMDPSyntaxError(lineno, "start exclude: excludes every state")
        return mask / mask.sum()
    toks = rest.split()
    if not toks:
        vec, lineno = _row(lines, n, lineno, "start")
    elif toks == ["uniform"]:
        vec = np.full(n, 1.0 / n)
    elif len(toks) == 1 and (toks[0].isdigit() or _IDENT.match(toks[0])) and not (n == 1 and "." in toks[0]):
        vec = np.zeros(n)
        vec[_index(toks[0], states, lineno, "state", wildcard=False)] = 1.0
    elif len(toks) == n:
        vec = np.array([_number(tok, lineno) for tok in toks])
    else:
        raise DPOMDPSyntaxError(lineno, f"start: expected {n} probabilities, 'uniform' or a state, got {rest!r}")
    if (vec < 0).any() or abs(vec.sum() - 1.0) > _PROB_TOL:
        raise DPOMDPSyntaxError(lineno, f"start: probabilities must be >= 0 and sum to 1, got {vec.tolist()}")
    return vec


def parse_dpomdp(text: str, check_probabilities: bool = True) -> DPOMDPModel:
    """Parse ``.dpomdp`` text.

    Args:
        text: the file contents.
        check_probabilities: require every ``T(.|s, ja)`` and ``O(.|ja, s')`` row to be a distribution
            (entries >= 0, sum within 1e-6 of 1, then renormalised); the error names the line that last
            wrote the offending row. Off only to inspect syntax-only files such as ``example.dpomdp``.

    Raises:
        DPOMDPSyntaxError: malformed input, with its line number.
    """
    if not isinstance(text, str):
        raise TypeError(f"text: expected str, got {type(text).__name__}")
    lines = _Lines(text)
    head = _header(lines)
    states, acts, obs = head["states"], head["actions"], head["observations"]
    n_s, n_ja, n_jo = len(states), int(np.prod([len(a) for a in acts])), int(np.prod([len(o) for o in obs]))
    trans = np.zeros((n_ja, n_s, n_s))
    obs_p = np.zeros((n_ja, n_s, n_jo))
    reward = np.zeros((n_ja, n_s, n_s, n_jo))
    t_line = np.zeros((n_ja, n_s), dtype=np.int64)  # line that last wrote each row, for error messages
    o_line = np.zeros((n_ja, n_s), dtype=np.int64)
    while (item := lines.peek()) is not None:
        lineno, text_line = lines.next("an entry")
        m = re.match(r"^([TOR])\s*:(.*)$", text_line)
        if not m:
            raise DPOMDPSyntaxError(lineno, f"expected a 'T:', 'O:' or 'R:' entry, got {text_line!r}")
        kind, fields = m.group(1), [f.strip() for f in m.group(2).split(":")]
        if len(fields) > 1 and fields[-1] == "":
            fields = fields[:-1]
        if any(f == "" for f in fields):
            raise DPOMDPSyntaxError(lineno, f"{kind}: empty field in {text_line!r}")
        ja = _joint(fields[0], acts, lineno, "action")
        if kind == "T":
            _entry_t(lines, lineno, fields, ja, states, trans, t_line)
        elif kind == "O":
            _entry_o(lines, lineno, fields, ja, states, obs, obs_p, o_line)
        else:
            _entry_r(lines, lineno, fields, ja, states, obs, reward)
    if check_probabilities:
        _check_rows(trans, t_line, "T", "transition", lines.last)
        _check_rows(obs_p, o_line, "O", "observation", lines.last)
        trans /= trans.sum(-1, keepdims=True)
        obs_p /= obs_p.sum(-1, keepdims=True)
    return DPOMDPModel(
        agent_names=head["agents"], state_names=states, action_names=acts, obs_names=obs,
        discount=head["discount"], start=head["start"], transition=trans, observation=obs_p,
        reward=-reward if head["values"] == "cost" else reward,
    )


def _ix(*lists: list[int]) -> tuple:
    return np.ix_(*[np.asarray(x) for x in lists])


def _entry_t(lines, lineno, fields, ja, states, trans, t_line) -> None:
    n = len(states)
    if len(fields) == 4:
        s = _index(fields[1], states, lineno, "state")
        s2 = _index(fields[2], states, lineno, "state")
        trans[_ix(ja, s, s2)] = _prob(fields[3], lineno)
        t_line[_ix(ja, s)] = lineno
    elif len(fields) == 2:
        s = _index(fields[1], states, lineno, "state")
        row, ln = _row(lines, n, lineno, "T row")
        trans[_ix(ja, s, list(range(n)))] = _probs(row, ln)
        t_line[_ix(ja, s)] = ln
    elif len(fields) == 1:
        mat, ln = _special(lines, (n, n), lineno, "T matrix", allow_identity=True)
        trans[ja] = _probs(mat, ln)
        t_line[ja] = ln
    else:
        raise DPOMDPSyntaxError(lineno, "T: expected 'T: ja : s : s2 : p', 'T: ja : s :' + row, or 'T: ja :' + matrix")


def _entry_o(lines, lineno, fields, ja, states, obs, obs_p, o_line) -> None:
    n_s, n_jo = obs_p.shape[1:]
    if len(fields) == 4:
        s2 = _index(fields[1], states, lineno, "state")
        jo = _joint(fields[2], obs, lineno, "observation")
        obs_p[_ix(ja, s2, jo)] = _prob(fields[3], lineno)
        o_line[_ix(ja, s2)] = lineno
    elif len(fields) == 2:
        s2 = _index(fields[1], states, lineno, "state")
        row, ln = _row(lines, n_jo, lineno, "O row")
        obs_p[_ix(ja, s2, list(range(n_jo)))] = _probs(row, ln)
        o_line[_ix(ja, s2)] = ln
    elif len(fields) == 1:
        mat, ln = _special(lines, (n_s, n_jo), lineno, "O matrix", allow_identity=True)
        obs_p[ja] = _probs(mat, ln)
        o_line[ja] = ln
    else:
        raise DPOMDPSyntaxError(lineno, "O: expected 'O: ja : s2 : jo : p', 'O: ja : s2 :' + row, or 'O: ja :' + matrix")


def _entry_r(lines, lineno, fields, ja, states, obs, reward) -> None:
    n_s, n_jo = reward.shape[2:]
    s = _index(fields[1], states, lineno, "state") if len(fields) >= 2 else None
    if len(fields) == 5:
        s2 = _index(fields[2], states, lineno, "state")
        jo = _joint(fields[3], obs, lineno, "observation")
        reward[_ix(ja, s, s2, jo)] = _number(fields[4], lineno)
    elif len(fields) == 3:
        s2 = _index(fields[2], states, lineno, "state")
        row, _ = _read_numbers(lines, n_jo, lineno, "R row")
        reward[_ix(ja, s, s2, list(range(n_jo)))] = row
    elif len(fields) == 2:
        mat, _ = _read_numbers(lines, n_s * n_jo, lineno, "R matrix")
        reward[_ix(ja, s, list(range(n_s)), list(range(n_jo)))] = mat.reshape(n_s, n_jo)
    else:
        raise DPOMDPSyntaxError(
            lineno, "R: expected 'R: ja : s : s2 : jo : r', 'R: ja : s : s2 :' + row, or 'R: ja : s :' + matrix"
        )


def _prob(tok: str, lineno: int) -> float:
    p = _number(tok, lineno)
    if not 0.0 <= p <= 1.0 + _PROB_TOL:
        raise DPOMDPSyntaxError(lineno, f"probability must lie in [0, 1], got {p}")
    return p


def _probs(values: np.ndarray, lineno: int) -> np.ndarray:
    if (values < 0).any() or (values > 1.0 + _PROB_TOL).any():
        raise DPOMDPSyntaxError(lineno, f"probabilities must lie in [0, 1], got {values.ravel().tolist()}")
    return values


def _check_rows(table: np.ndarray, line_of: np.ndarray, kind: str, what: str, end_line: int) -> None:
    sums = table.sum(-1)
    bad = np.argwhere(np.abs(sums - 1.0) > _PROB_TOL)
    if len(bad):
        ja, s = (int(v) for v in bad[0])
        where = int(line_of[ja, s])
        detail = "never specified" if where == 0 else f"sums to {sums[ja, s]:.6g}"
        raise DPOMDPSyntaxError(
            where or end_line, f"{kind}: {what} probabilities for joint action {ja}, state {s} {detail} (must sum to 1)"
        )


def load_dpomdp(path: str | os.PathLike, check_probabilities: bool = True) -> DPOMDPModel:
    """Read and parse a ``.dpomdp`` file; see :func:`parse_dpomdp`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    try:
        return parse_dpomdp(path.read_text(), check_probabilities)
    except DPOMDPSyntaxError as exc:
        raise DPOMDPSyntaxError(exc.lineno, f"{path.name}: {str(exc).split(': ', 1)[1]}") from None
