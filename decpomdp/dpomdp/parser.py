"""Parser for the MADP toolbox's ``.dpomdp`` text format (plain or gzipped).

Every form documented by ``example.dpomdp`` is read: the header (``agents``, ``discount``,
``values``, ``states``, ``start``, ``actions``, ``observations``, in that order, each once;
counts or name lists), the four ``start`` forms (a probability vector on the next line or the
same line, ``uniform``, one state by name or index, ``start include:`` / ``start exclude:``),
and ``T``/``O``/``R`` entries in single-number, row and matrix forms, with ``uniform`` and
``identity``, names or indices, ``*`` wildcards, joint actions/observations given by index or
by their per-agent components (indices, names or ``*``). Later entries overwrite earlier ones.
Joint indices put the first agent's component most significant. ``values: cost`` negates rewards.

The result is compact (see :mod:`decpomdp.dpomdp.model`): sparse transitions, and a reward table
over only the indices some entry distinguishes. Nothing is sized from the header before the
``memory_budget`` check: declared sizes whose tables would exceed it are rejected at the line that
declares them, with the bytes they would need. Numbers must be finite.

Blank lines and lines starting with ``#`` are skipped. Any error raises :class:`DPOMDPSyntaxError`
(a ``ValueError``) whose message starts with ``line N:``.
"""

from __future__ import annotations

import gzip
import math
import os
import re
import zlib
from pathlib import Path

import numpy as np

from decpomdp.dpomdp.entries import parse_entries
from decpomdp.dpomdp.model import DPOMDPModel
from decpomdp.dpomdp.syntax import (
    DEFAULT_MEMORY_BUDGET,
    HEADER,
    IDENT,
    NAME_BYTES,
    PROB_TOL,
    TEXT_BYTES,
    DPOMDPSyntaxError,
    Index,
    Lines,
    check_budget,
    gib,
    is_index,
    model_bytes,
    number,
    row_block,
)


def _names(rest: str, lineno: int, what: str, budget: int) -> list[str]:
    """A count (``3`` -> ['0', '1', '2'] as index names) or a list of identifiers."""
    toks = rest.split()
    if not toks:
        raise DPOMDPSyntaxError(lineno, f"expected a count or a list of {what} names")
    if len(toks) == 1 and is_index(toks[0]):
        n = int(toks[0])
        if n < 1:
            raise DPOMDPSyntaxError(lineno, f"expected at least one {what}, got {n}")
        check_budget(n * NAME_BYTES, budget, lineno, f"{n} {what}s")
        return [str(i) for i in range(n)]
    for tok in toks:
        if not IDENT.match(tok):
            raise DPOMDPSyntaxError(
                lineno, f"{tok!r} is not a valid {what} name (a letter then alphanumerics, '-', '_')"
            )
    if len(set(toks)) != len(toks):
        raise DPOMDPSyntaxError(lineno, f"duplicate {what} names in {toks[:20]}")
    return toks


def _header(lines: Lines, budget: int) -> dict:
    out: dict = {}
    for key in HEADER:
        lineno, text = lines.next(f"'{key}:'")
        m = re.match(r"^(\w+)(\s+(include|exclude))?\s*:(.*)$", text)
        if not m or m.group(1) != key:
            raise DPOMDPSyntaxError(lineno, f"expected '{key}:' (header entries come in the order {', '.join(HEADER)})")
        if m.group(3) and key != "start":
            raise DPOMDPSyntaxError(lineno, f"'{m.group(3)}' only applies to 'start'")
        rest = m.group(4).strip()
        if key == "agents":
            out["agents"] = _names(rest, lineno, "agent", budget)
        elif key == "discount":
            out["discount"] = number(rest, lineno)
            if not 0.0 <= out["discount"] <= 1.0:
                raise DPOMDPSyntaxError(lineno, f"discount must lie in [0, 1], got {out['discount']}")
        elif key == "values":
            if rest not in ("reward", "cost"):
                raise DPOMDPSyntaxError(lineno, f"values: expected 'reward' or 'cost', got {rest!r}")
            out["values"] = rest
        elif key == "states":
            out["states"] = _names(rest, lineno, "state", budget)
            check_budget(model_bytes(len(out["states"]), 1, 1), budget, lineno, f"{len(out['states'])} states")
        elif key == "start":
            out["start"] = _start(lines, lineno, m.group(3), rest, out["states"])
        else:
            n_agents = len(out["agents"])
            if rest:
                raise DPOMDPSyntaxError(lineno, f"{key}: the per-agent lists go on the following {n_agents} lines")
            what = key[:-1] if key == "actions" else "observation"
            out[key] = []
            for a in range(n_agents):
                ln, text_a = lines.next(f"{what}s of agent {a}")
                if re.match(r"^\w+\s*:", text_a):  # the next section: fewer lists than agents
                    raise DPOMDPSyntaxError(
                        ln,
                        f"{key}: expected one list per agent ({n_agents} agents declared by "
                        f"'agents:'), found {a} before {text_a.split(':')[0]!r}:",
                    )
                out[key].append(_names(text_a, ln, what, budget))
                n_ja = math.prod(len(x) for x in out["actions"])
                n_jo = math.prod(len(x) for x in out.get("observations", [[0]]))
                check_budget(
                    model_bytes(len(out["states"]), n_ja, n_jo),
                    budget,
                    ln,
                    f"{len(out['states'])} states, {n_ja} joint actions and {n_jo} joint observations",
                )
    return out


def _start(lines: Lines, lineno: int, mode: str | None, rest: str, states: list[str]) -> np.ndarray:
    n = len(states)
    index = Index(states, "state")
    if mode:
        toks = rest.split()
        chosen = sorted({int(i) for tok in toks for i in index(tok, lineno, wildcard=False)})
        if not len(chosen):
            raise DPOMDPSyntaxError(lineno, f"start {mode}: expected a list of states")
        mask = np.zeros(n, dtype=bool)
        mask[chosen] = True
        mask = mask if mode == "include" else ~mask
        if not mask.any():
            raise DPOMDPSyntaxError(lineno, "start exclude: excludes every state")
        return mask / mask.sum()
    toks = rest.split()
    if not toks:
        row, lineno = row_block(lines, n, lineno, "start")
        vec = np.full(n, 1.0 / n) if isinstance(row, str) else row
    elif toks == ["uniform"]:
        vec = np.full(n, 1.0 / n)
    elif len(toks) == 1 and (is_index(toks[0]) or IDENT.match(toks[0])) and not (n == 1 and "." in toks[0]):
        vec = np.zeros(n)
        vec[index(toks[0], lineno, wildcard=False)] = 1.0
    elif len(toks) == n:
        vec = np.array([number(tok, lineno) for tok in toks])
    else:
        raise DPOMDPSyntaxError(lineno, f"start: expected {n} probabilities, 'uniform' or a state, got {rest!r}")
    if (vec < 0).any() or abs(vec.sum() - 1.0) > PROB_TOL:
        raise DPOMDPSyntaxError(lineno, f"start: probabilities must be >= 0 and sum to 1, got {vec.tolist()[:20]}")
    return vec


def parse_dpomdp(
    text: str, check_probabilities: bool = True, memory_budget: int = DEFAULT_MEMORY_BUDGET
) -> DPOMDPModel:
    """Parse ``.dpomdp`` text.

    Args:
        text: the file contents.
        check_probabilities: require every ``T(.|s, ja)`` and ``O(.|ja, s')`` row to be a distribution
            (entries >= 0, sum within 1e-6 of 1, then renormalised); the error names the line that last
            wrote the offending row. Off only to inspect syntax-only files such as ``example.dpomdp``.
        memory_budget: bytes the model may occupy; a header or entry that would need more is rejected
            before anything of that size is allocated.

    Raises:
        DPOMDPSyntaxError: malformed input, with its line number.
    """
    if not isinstance(text, str):
        raise TypeError(f"text: expected str, got {type(text).__name__}")
    if not isinstance(memory_budget, int) or memory_budget < 1:
        raise ValueError(f"memory_budget: expected a number of bytes >= 1, got {memory_budget!r}")
    nul = text.find("\x00")
    if nul >= 0:
        raise DPOMDPSyntaxError(text.count("\n", 0, nul) + 1, "binary data (a NUL character): not a .dpomdp text file")
    check_budget(len(text) * TEXT_BYTES, memory_budget, 1, f"parsing {len(text)} characters of text would")
    lines = Lines(text)
    head = _header(lines, memory_budget)
    return parse_entries(lines, head, check_probabilities, memory_budget)


def _read_bytes(path: Path, budget: int) -> bytes:
    """The file's bytes, gunzipped when it starts with the gzip magic number (at most ``budget`` bytes)."""
    with open(path, "rb") as f:
        data = f.read(budget + 1)
    if data[:2] == b"\x1f\x8b":
        try:
            with open(path, "rb") as raw, gzip.GzipFile(fileobj=raw) as g:
                data = g.read(budget + 1)
        except (OSError, EOFError, zlib.error) as exc:
            raise DPOMDPSyntaxError(1, f"{path.name}: not a valid gzip file ({exc})") from None
    if len(data) > budget:
        raise DPOMDPSyntaxError(1, f"{path.name}: the file holds more than the memory budget of {gib(budget)}")
    return data


def load_dpomdp(
    path: str | os.PathLike, check_probabilities: bool = True, memory_budget: int = DEFAULT_MEMORY_BUDGET
) -> DPOMDPModel:
    """Read and parse a ``.dpomdp`` or gzipped ``.dpomdp.gz`` file; see :func:`parse_dpomdp`.

    Raises:
        FileNotFoundError: no such file.
        DPOMDPSyntaxError: malformed, binary or non-UTF-8 content; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"path: {str(path)!r} is a folder, expected a .dpomdp file")
    if not path.is_file():
        raise FileNotFoundError(f"path: no such file {str(path)!r}")
    data = _read_bytes(path, memory_budget)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise DPOMDPSyntaxError(
            line,
            f"{path.name}: not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); is this a binary file?",
        ) from None
    try:
        return parse_dpomdp(text, check_probabilities, memory_budget)
    except DPOMDPSyntaxError as exc:
        raise DPOMDPSyntaxError(exc.lineno, f"{path.name}: {str(exc).split(': ', 1)[1]}") from None
