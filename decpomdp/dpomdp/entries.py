"""The ``T:``, ``O:`` and ``R:`` entries of a ``.dpomdp`` body, built into compact tables.

Entries overwrite each other in file order. Transitions are kept as *row writes* (a whole row
``T(. | s, ja)`` at once: a row of numbers, a matrix row, ``uniform``, ``identity`` or ``* : p``) and
*single writes* (one ``(ja, s, s')`` entry); at the end every row is its last row write patched by
the single writes after it, stored as CSR. Rewards are kept as a list of writes and laid into an
array over only the indices some write distinguishes. Observations are a dense (JA, S', JO) table.
Every growth is checked against the memory budget at the line that causes it.
"""

from __future__ import annotations

import math

import numpy as np

from decpomdp.dpomdp.model import DPOMDPModel, SparseTransitions
from decpomdp.dpomdp.syntax import (
    PROB_TOL,
    ROUNDING,
    DPOMDPSyntaxError,
    Index,
    Joint,
    Lines,
    check_budget,
    matrix_block,
    number,
    prob,
    probs,
    read_numbers,
    row_block,
)

_TRIPLET_BYTES = 40  # one transition entry while tables are built (row, column, value, line, sort keys)


def _ix(*index: np.ndarray) -> tuple:
    """``np.ix_`` for index arrays, with plain ints when every array holds one index (much cheaper)."""
    scalars = []
    for a in index:
        if a.size != 1:
            break
        scalars.append(int(a[0]))
    else:
        return tuple(scalars)
    k = len(index)
    return tuple(a.reshape([-1 if j == i else 1 for j in range(k)]) for i, a in enumerate(index))


class _Transitions:
    """Row writes and single writes of ``T``, resolved into CSR by :meth:`build`."""

    def __init__(self, n_ja: int, n_s: int, budget: int) -> None:
        self.n_ja, self.n_s, self.budget = n_ja, n_s, budget
        self.records: list[tuple[int, int, np.ndarray, object]] = []  # (seq, line, rows, payload)
        self.rows: list[int] = []  # single writes: row ja * S + s, column s', value, line (= seq)
        self.cols: list[int] = []
        self.vals: list[float] = []
        self.lines: list[int] = []
        self.entries = 0  # upper bound on stored entries, for the budget
        self.prefixes: set[str] = set()  # raw fields of validated single writes: 'T' part,
        self.ja_of: dict[str, int] = {}  # joint action,
        self.state_of: dict[str, int] = {}  # state or next state

    def _grow(self, count: int, lineno: int) -> None:
        self.entries += count
        check_budget(self.entries * _TRIPLET_BYTES, self.budget, lineno, f"{self.entries} transition entries")

    def row_write(self, seq: int, line: int, ja: np.ndarray, s: np.ndarray, payload: str | float | np.ndarray) -> None:
        """Rows (ja x s) set to ``payload``: 'uniform', 'identity', a float, (S',) or (S, S') values."""
        rows = (ja[:, None] * self.n_s + s[None, :]).ravel()
        self._grow(rows.size * (1 if isinstance(payload, str) and payload == "identity" else self.n_s), seq)
        self.records.append((seq, line, rows, payload))

    def single(self, line: int, ja: np.ndarray, s: np.ndarray, s2: int, p: float) -> None:
        rows = (ja[:, None] * self.n_s + s[None, :]).ravel().tolist()
        self._grow(len(rows), line)
        self.rows += rows
        self.cols += [s2] * len(rows)
        self.vals += [p] * len(rows)
        self.lines += [line] * len(rows)

    def remember(self, parts: list[str], ja: np.ndarray, s: np.ndarray, s2: int) -> None:
        """Cache a validated single write's raw fields, so :meth:`fast_single` can take later lines that reuse them."""
        self.prefixes.add(parts[0])
        if ja.size == 1:
            self.ja_of[parts[1]] = int(ja[0])
        if s.size == 1:
            self.state_of[parts[2]] = int(s[0])
        self.state_of[parts[3]] = s2

    def fast_single(self, parts: list[str], line: int) -> bool:
        """Take ``T: ja : s : s2 : p`` (split on ':') if its raw fields were seen before and ``p`` is a probability."""
        if parts[0] not in self.prefixes:
            return False
        ja, s, s2 = self.ja_of.get(parts[1]), self.state_of.get(parts[2]), self.state_of.get(parts[3])
        if ja is None or s is None or s2 is None:
            return False
        try:
            p = float(parts[4])
        except ValueError:
            return False
        if not 0.0 <= p <= 1.0 + PROB_TOL:  # also rejects nan: the general path reports it
            return False
        self.rows.append(ja * self.n_s + s)
        self.cols.append(s2)
        self.vals.append(p)
        self.lines.append(line)
        return True

    def _record_entries(self, base: np.ndarray) -> list[np.ndarray]:
        """[row, col, value, seq] of every entry that the row writes still in force put in their rows."""
        n_s = self.n_s
        parts: list[tuple[np.ndarray, ...]] = [
            (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64))
        ]
        for r, (seq, _, _, payload) in enumerate(self.records):
            rows = np.flatnonzero(base == r)
            if rows.size == 0:
                continue
            if isinstance(payload, str) and payload == "identity":
                row, col, val = rows, rows % n_s, np.ones(rows.size)
            else:
                row, col = np.repeat(rows, n_s), np.tile(np.arange(n_s), rows.size)
                if isinstance(payload, str):  # uniform
                    val = np.full(row.size, 1.0 / n_s)
                elif isinstance(payload, float):
                    val = np.full(row.size, payload)
                else:  # one row for every s, or a matrix indexed by s
                    val = (payload[rows % n_s] if payload.ndim == 2 else np.tile(payload, rows.size)).ravel()
            parts.append((row, col, val, np.full(row.size, seq)))
        return [np.concatenate(p) for p in zip(*parts)]

    def build(self) -> tuple[SparseTransitions, np.ndarray]:
        """The CSR table and, per row, the line that last wrote it (0 = never)."""
        n_rows, n_s = self.n_ja * self.n_s, self.n_s
        base = np.full(n_rows, -1, dtype=np.int64)
        base_seq = np.zeros(n_rows, dtype=np.int64)
        line_of = np.zeros(n_rows, dtype=np.int64)
        for r, (seq, line, rows, _) in enumerate(self.records):
            base[rows], base_seq[rows], line_of[rows] = r, seq, line
        rows = np.asarray(self.rows, dtype=np.int64)
        cols = np.asarray(self.cols, dtype=np.int64)
        vals = np.asarray(self.vals, dtype=np.float64)
        seqs = np.asarray(self.lines, dtype=np.int64)
        keep = seqs > base_seq[rows]  # single writes after their row's last row write
        rows, cols, vals, seqs = rows[keep], cols[keep], vals[keep], seqs[keep]
        np.maximum.at(line_of, rows, seqs)
        r_rows, r_cols, r_vals, r_seqs = self._record_entries(base)
        rows, cols = np.concatenate([r_rows, rows]), np.concatenate([r_cols, cols])
        vals, seqs = np.concatenate([r_vals, vals]), np.concatenate([r_seqs, seqs])
        key = rows * n_s + cols
        order = np.lexsort((seqs, key))  # by (row, col), then file order
        key, vals = key[order], vals[order]
        last = np.ones(key.size, dtype=bool)
        last[:-1] = key[1:] != key[:-1]  # the last write of every (row, col) wins
        key, vals = key[last], vals[last]
        nz = vals != 0
        key, vals = key[nz], vals[nz]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(key // n_s, minlength=n_rows))])
        return SparseTransitions(self.n_ja, n_s, indptr, key % n_s, vals), line_of.reshape(self.n_ja, n_s)


class _Rewards:
    """Reward writes in file order, laid into an array over the indices they distinguish."""

    def __init__(self, sizes: tuple[int, int, int, int], budget: int) -> None:
        self.sizes, self.budget = sizes, budget
        self.writes: list[tuple[tuple[np.ndarray | None, ...], object]] = []
        self.varies = [False] * 4

    def write(self, lineno: int, index: list[np.ndarray | None], value: float | np.ndarray) -> None:
        """``index`` per dimension (None = all, with ``value`` varying along it)."""
        grew = False
        for d, ix in enumerate(index):
            if not self.varies[d] and (ix is None or ix.size != self.sizes[d]):
                self.varies[d] = grew = True
        if grew:
            shape = [n if v else 1 for n, v in zip(self.sizes, self.varies)]
            check_budget(8 * math.prod(shape), self.budget, lineno, f"a reward table of shape {tuple(shape)} would")
        self.writes.append((tuple(index), value))

    def build(self) -> np.ndarray:
        shape = [n if v else 1 for n, v in zip(self.sizes, self.varies)]
        out = np.zeros(shape)
        zero = np.zeros(1, dtype=np.int64)
        for index, value in self.writes:  # None dimensions are trailing: the value varies along them
            lead = [ix if self.varies[d] else zero for d, ix in enumerate(index) if ix is not None]
            out[_ix(*lead) + (slice(None),) * (4 - len(lead))] = value
        return out


def _t_entry(lines: Lines, lineno: int, fields: list[str], ja: np.ndarray, state: Index, table: _Transitions) -> None:
    n = table.n_s
    if len(fields) == 4:
        s = state(fields[1], lineno)
        table.row_write(lineno, lineno, ja, s, prob(fields[3], lineno))  # s2 = '*': the whole row
    elif len(fields) == 2:
        s = state(fields[1], lineno)
        row, ln = row_block(lines, n, lineno, "T row")
        table.row_write(lineno, ln, ja, s, probs(row, ln))
    elif len(fields) == 1:
        mat, ln = matrix_block(lines, (n, n), lineno, "T matrix")
        table.row_write(lineno, ln, ja, state.all, probs(mat, ln))
    else:
        raise DPOMDPSyntaxError(lineno, "T: expected 'T: ja : s : s2 : p', 'T: ja : s :' + row, or 'T: ja :' + matrix")


def _o_entry(
    lines: Lines,
    lineno: int,
    fields: list[str],
    ja: np.ndarray,
    state: Index,
    jo_of: Joint,
    obs: np.ndarray,
    o_line: np.ndarray,
) -> None:
    n_s, n_jo = obs.shape[1:]
    if len(fields) == 4:
        s2, jo = state(fields[1], lineno), jo_of(fields[2], lineno)
        obs[_ix(ja, s2, jo)] = prob(fields[3], lineno)
        o_line[_ix(ja, s2)] = lineno
    elif len(fields) == 2:
        s2 = state(fields[1], lineno)
        row, ln = row_block(lines, n_jo, lineno, "O row")
        obs[_ix(ja, s2)] = 1.0 / n_jo if isinstance(row, str) else probs(row, ln)
        o_line[_ix(ja, s2)] = ln
    elif len(fields) == 1:
        mat, ln = matrix_block(lines, (n_s, n_jo), lineno, "O matrix")
        if isinstance(mat, str):
            obs[ja] = 1.0 / n_jo if mat == "uniform" else np.eye(n_s)
        else:
            obs[ja] = probs(mat, ln)
        o_line[ja] = ln
    else:
        raise DPOMDPSyntaxError(
            lineno, "O: expected 'O: ja : s2 : jo : p', 'O: ja : s2 :' + row, or 'O: ja :' + matrix"
        )


def _r_entry(
    lines: Lines, lineno: int, fields: list[str], ja: np.ndarray, state: Index, jo_of: Joint, rewards: _Rewards
) -> None:
    n_s, n_jo = rewards.sizes[2:]
    s = state(fields[1], lineno) if len(fields) >= 2 else None
    if len(fields) == 5:
        s2, jo = state(fields[2], lineno), jo_of(fields[3], lineno)
        rewards.write(lineno, [ja, s, s2, jo], number(fields[4], lineno))
    elif len(fields) == 3:
        s2 = state(fields[2], lineno)
        row, _ = read_numbers(lines, n_jo, lineno, "R row")
        rewards.write(lineno, [ja, s, s2, None], row)
    elif len(fields) == 2:
        mat, _ = read_numbers(lines, n_s * n_jo, lineno, "R matrix")
        rewards.write(lineno, [ja, s, None, None], mat.reshape(n_s, n_jo))
    else:
        raise DPOMDPSyntaxError(
            lineno, "R: expected 'R: ja : s : s2 : jo : r', 'R: ja : s : s2 :' + row, or 'R: ja : s :' + matrix"
        )


def _check_rows(sums: np.ndarray, line_of: np.ndarray, kind: str, what: str, end_line: int) -> None:
    bad = np.argwhere(np.abs(sums - 1.0) > PROB_TOL)
    if len(bad):
        ja, s = (int(v) for v in bad[0])
        where = int(line_of[ja, s])
        detail = "never specified" if where == 0 else f"sums to {sums[ja, s]:.6g}"
        raise DPOMDPSyntaxError(
            where or end_line, f"{kind}: {what} probabilities for joint action {ja}, state {s} {detail} (must sum to 1)"
        )


def _split(text: str, lineno: int) -> tuple[str, list[str]]:
    """``'T: a : b'`` -> ('T', ['a', 'b']), validating the entry's shape."""
    colon = text.find(":")
    kind = text[0]
    if kind not in "TOR" or colon < 0 or text[1:colon].strip():
        raise DPOMDPSyntaxError(lineno, f"expected a 'T:', 'O:' or 'R:' entry, got {text[:80]!r}")
    fields = [f.strip() for f in text[colon + 1 :].split(":")]
    if len(fields) > 1 and fields[-1] == "":
        fields.pop()
    if "" in fields:
        raise DPOMDPSyntaxError(lineno, f"{kind}: empty field in {text[:80]!r}")
    return kind, fields


def parse_entries(lines: Lines, head: dict, check_probabilities: bool, budget: int) -> DPOMDPModel:
    """Read every entry after the header and build the model (see :func:`decpomdp.dpomdp.parse_dpomdp`)."""
    states, acts, obs_names = head["states"], head["actions"], head["observations"]
    ja_of, jo_of, state = Joint(acts, "action"), Joint(obs_names, "observation"), Index(states, "state")
    n_s, n_ja, n_jo = len(states), ja_of.total, jo_of.total
    trans = _Transitions(n_ja, n_s, budget)
    obs = np.zeros((n_ja, n_s, n_jo))
    o_line = np.zeros((n_ja, n_s), dtype=np.int64)
    rewards = _Rewards((n_ja, n_s, n_s, n_jo), budget)
    items = lines.items
    while lines.pos < len(items):
        lineno, text = items[lines.pos]
        lines.pos += 1
        if text[0] == "T":
            parts = text.split(":")
            if len(parts) == 5 and trans.fast_single(parts, lineno):
                continue
        kind, fields = _split(text, lineno)
        ja = ja_of(fields[0], lineno)
        if kind == "T" and len(fields) == 4 and fields[2] != "*":  # a single write
            s, s2 = state(fields[1], lineno), int(state(fields[2], lineno)[0])
            trans.single(lineno, ja, s, s2, prob(fields[3], lineno))
            if len(parts) == 5:
                trans.remember(parts, ja, s, s2)
        elif kind == "T":
            _t_entry(lines, lineno, fields, ja, state, trans)
        elif kind == "O":
            _o_entry(lines, lineno, fields, ja, state, jo_of, obs, o_line)
        else:
            _r_entry(lines, lineno, fields, ja, state, jo_of, rewards)
    transition, t_line = trans.build()
    if check_probabilities:
        _check_rows(transition.row_sums(), t_line, "T", "transition", lines.last)
        _check_rows(obs.sum(-1), o_line, "O", "observation", lines.last)
        t_sums = transition.row_sums().ravel()
        transition.data /= np.where(np.abs(t_sums - 1.0) > ROUNDING, t_sums, 1.0)[transition.rows()]
        o_sums = obs.sum(-1, keepdims=True)
        obs /= np.where(np.abs(o_sums - 1.0) > ROUNDING, o_sums, 1.0)
    reward = rewards.build()
    return DPOMDPModel(
        agent_names=head["agents"],
        state_names=states,
        action_names=acts,
        obs_names=obs_names,
        discount=head["discount"],
        start=head["start"],
        transition=transition,
        observation=obs,
        reward=-reward if head["values"] == "cost" else reward,
    )
