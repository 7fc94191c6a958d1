"""Tokens of the ``.dpomdp`` format: the error type, content lines, index specs, number blocks, budgets."""

from __future__ import annotations

import math
import re

import numpy as np

IDENT = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
ENTRY = re.compile(r"^[TOR]\s*:")
HEADER = ("agents", "discount", "values", "states", "start", "actions", "observations")
PROB_TOL = 1e-6
ROUNDING = 1e-12
"""A distribution whose sum is within this of 1 is kept as written (renormalising it again would move it by
rounding alone, and a written model would not read back the same)."""
DEFAULT_MEMORY_BUDGET = 2 * 1024**3
"""Bytes the parsed model may occupy by default (2 GiB)."""
NAME_BYTES = 64  # a generated name ('1234') with its list slot and index entry
TEXT_BYTES = 24  # parser working memory per character of text (line list, tokens)


class DPOMDPSyntaxError(ValueError):
    """A malformed ``.dpomdp`` file; ``lineno`` is the 1-based line of the problem."""

    def __init__(self, lineno: int, message: str) -> None:
        super().__init__(f"line {lineno}: {message}")
        self.lineno = lineno


def is_index(tok: str) -> bool:
    """ASCII digits only (``str.isdigit`` also accepts characters such as '²' that ``int`` rejects)."""
    return tok.isascii() and tok.isdigit()


def number(tok: str, lineno: int) -> float:
    try:
        value = float(tok)
    except ValueError:
        raise DPOMDPSyntaxError(lineno, f"expected a number, got {tok!r}") from None
    if not math.isfinite(value):
        raise DPOMDPSyntaxError(lineno, f"expected a finite number, got {tok!r}")
    return value


def gib(n: float) -> str:
    return f"{n:.0f} bytes ({n / 1024**3:.3g} GiB)"


def check_budget(needed: float, budget: int, lineno: int, what: str) -> None:
    if needed > budget:
        raise DPOMDPSyntaxError(lineno, f"{what} need {gib(needed)}, above the memory budget of {gib(budget)}")


def model_bytes(n_s: int, n_ja: int, n_jo: int) -> int:
    """Least memory the model needs: start, names, O (JA, S, JO), per-row T and reward tables."""
    return n_s * (8 + NAME_BYTES) + n_ja * n_s * (8 * n_jo + 4 + 8 + 8 + 8 + 8)


class Lines:
    """Content lines (number, text) with comments and blank lines removed."""

    def __init__(self, text: str) -> None:
        raw = text.splitlines()
        self.items = [(i + 1, s) for i, line in enumerate(raw) if (s := line.strip()) and s[0] != "#"]
        self.pos = 0
        self.last = len(raw)

    def peek(self) -> tuple[int, str] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[int, str]:
        if self.pos >= len(self.items):
            raise DPOMDPSyntaxError(self.last, f"unexpected end of file, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]


class Index:
    """Indices denoted by a name, an index or ``*`` (cached per token)."""

    def __init__(self, names: list[str], what: str) -> None:
        self.n, self.what = len(names), what
        self.lookup = {name: i for i, name in enumerate(names)}
        self.all = np.arange(self.n)
        self.cache: dict[str, np.ndarray] = {}

    def __call__(self, tok: str, lineno: int, wildcard: bool = True) -> np.ndarray:
        hit = self.cache.get(tok)
        if hit is not None and (wildcard or tok != "*"):
            return hit
        if tok == "*" and wildcard:
            out = self.all
        elif is_index(tok):
            i = int(tok)
            if i >= self.n:
                raise DPOMDPSyntaxError(lineno, f"{self.what} index {i} out of range (there are {self.n})")
            out = np.array([i])
        elif tok in self.lookup:
            out = np.array([self.lookup[tok]])
        else:
            known = " ".join(list(self.lookup)[:12]) + (" ..." if self.n > 12 else "")
            raise DPOMDPSyntaxError(lineno, f"unknown {self.what} {tok!r} (known: {known})")
        self.cache[tok] = out
        return out


class Joint:
    """Joint indices for a joint action/observation spec: ``*``, a joint index, or one token per agent."""

    def __init__(self, per_agent: list[list[str]], what: str) -> None:
        self.parts = [Index(names, f"{what} of agent {a}") for a, names in enumerate(per_agent)]
        self.sizes = [len(n) for n in per_agent]
        self.total = math.prod(self.sizes)
        self.strides = np.cumprod([1] + self.sizes[::-1][:-1])[::-1]
        self.what = what
        self.cache: dict[str, np.ndarray] = {}

    def __call__(self, spec: str, lineno: int) -> np.ndarray:
        hit = self.cache.get(spec)
        if hit is not None:
            return hit
        toks = spec.split()
        if len(toks) == 1 and len(self.parts) > 1:
            if toks[0] == "*":
                out = np.arange(self.total)
            elif is_index(toks[0]) and int(toks[0]) < self.total:
                out = np.array([int(toks[0])])
            elif is_index(toks[0]):
                raise DPOMDPSyntaxError(
                    lineno, f"joint {self.what} index {toks[0]} out of range (there are {self.total})"
                )
            else:
                raise DPOMDPSyntaxError(
                    lineno, f"unknown joint {self.what} {toks[0]!r} (a joint index, '*', or one per agent)"
                )
        elif len(toks) != len(self.parts):
            raise DPOMDPSyntaxError(
                lineno, f"joint {self.what} {spec.strip()!r}: expected 1 or {len(self.parts)} components"
            )
        else:
            out = np.zeros(1, dtype=np.int64)
            for part, tok, stride in zip(self.parts, toks, self.strides):  # first agent most significant
                out = (out[:, None] + part(tok, lineno)[None, :] * int(stride)).ravel()
        self.cache[spec] = out
        return out


def read_numbers(lines: Lines, count: int, lineno: int, what: str) -> tuple[np.ndarray, int]:
    """Read ``count`` finite numbers from the following lines (``uniform``/``identity`` handled by callers)."""
    values: list[float] = []
    last = lineno
    items, pos = lines.items, lines.pos
    while len(values) < count:
        if pos >= len(items) or ENTRY.match(items[pos][1]):
            lines.pos = pos
            where = items[pos][0] if pos < len(items) else lines.last
            raise DPOMDPSyntaxError(where, f"{what}: expected {count} numbers, got {len(values)}")
        last, text = items[pos]
        pos += 1
        toks = text.split()
        if len(values) + len(toks) > count:
            raise DPOMDPSyntaxError(last, f"{what}: expected {count} numbers, got at least {len(values) + len(toks)}")
        try:
            row = [float(tok) for tok in toks]
        except ValueError:
            row = [number(tok, last) for tok in toks]  # raises, naming the token
        if not all(map(math.isfinite, row)):
            row = [number(tok, last) for tok in toks]
        values.extend(row)
    lines.pos = pos
    return np.asarray(values, dtype=np.float64), last


def matrix_block(lines: Lines, shape: tuple[int, int], lineno: int, what: str) -> tuple[str | np.ndarray, int]:
    """A matrix on the following lines: ``'uniform'``, ``'identity'`` (square only) or rows of numbers."""
    nxt = lines.peek()
    if nxt is not None and nxt[1] in ("uniform", "identity"):
        ln, word = lines.next(what)
        if word == "identity" and shape[0] != shape[1]:
            raise DPOMDPSyntaxError(
                ln, f"{what}: 'identity' needs a square matrix, this one is {shape[0]} x {shape[1]}"
            )
        return word, ln
    values, ln = read_numbers(lines, shape[0] * shape[1], lineno, what)
    return values.reshape(shape), ln


def row_block(lines: Lines, n: int, lineno: int, what: str) -> tuple[str | np.ndarray, int]:
    nxt = lines.peek()
    if nxt is not None and nxt[1] == "uniform":
        ln, _ = lines.next(what)
        return "uniform", ln
    return read_numbers(lines, n, lineno, what)


def prob(tok: str, lineno: int) -> float:
    p = number(tok, lineno)
    if not 0.0 <= p <= 1.0 + PROB_TOL:
        raise DPOMDPSyntaxError(lineno, f"probability must lie in [0, 1], got {p}")
    return p


def probs(values: str | np.ndarray, lineno: int) -> str | np.ndarray:
    if not isinstance(values, str) and ((values < 0).any() or (values > 1.0 + PROB_TOL).any()):
        raise DPOMDPSyntaxError(lineno, f"probabilities must lie in [0, 1], got {values.ravel().tolist()[:20]}")
    return values
