"""Random ``.dpomdp`` texts that exercise every entry form, with overwrites in file order.

``tests/decpomdp/data/parser_reference.npz`` holds such texts together with the tables the
dense parser of commit 0aad4c6 (the implementation this package replaced) produced for them, so
that the compact parser is checked against it without keeping two parsers. Regenerate with
``python tests/decpomdp/dpomdp_synthetic.py OLD_PARSER.py OUT.npz`` (``OLD_PARSER.py`` exposes
``parse_dpomdp`` and ``load_dpomdp`` returning dense ``transition``, ``observation`` and ``reward``
arrays); the archive also holds the dense tables of the shipped problems.
"""

from __future__ import annotations

import itertools
import random


def _names(rng: random.Random, n: int, prefix: str) -> tuple[list[str], str]:
    """Names as a count (index names) or a list of identifiers; returns (names, header text)."""
    if rng.random() < 0.4:
        return [str(i) for i in range(n)], str(n)
    names = [f"{prefix}{i}-{rng.choice('xyz')}" for i in range(n)]
    return names, " ".join(names)


def _component(rng: random.Random, names: list[str]) -> str:
    r = rng.random()
    if r < 0.25:
        return "*"
    i = rng.randrange(len(names))
    return names[i] if r < 0.6 else str(i)


def _joint(rng: random.Random, per_agent: list[list[str]]) -> str:
    r = rng.random()
    if r < 0.2:
        return "*"
    if r < 0.4:
        total = 1
        for names in per_agent:
            total *= len(names)
        return str(rng.randrange(total))
    return " ".join(_component(rng, names) for names in per_agent)


def _numbers(rng: random.Random, n: int, per_line: int, prob: bool = True) -> str:
    """``n`` numbers, ``per_line`` a line: probabilities in [0, 1], or any rewards."""
    pool = (
        (lambda: rng.choice([0.0, 1, round(rng.random(), 3)]))
        if prob
        else (lambda: rng.choice([0.0, round(rng.random(), 3), rng.randint(-5, 5)]))
    )
    vals = [f"{pool()}" for _ in range(n)]
    return "\n".join(" ".join(vals[i : i + per_line]) for i in range(0, n, per_line))


def synthetic_text(seed: int) -> str:
    """One random file: 2 or 3 agents, a random mix of every T/O/R form (probabilities unchecked)."""
    rng = random.Random(seed)
    n_agents = rng.choice([2, 2, 3])
    n_s = rng.randint(1, 4)
    states, s_head = _names(rng, n_s, "s")
    acts, obs, a_head, o_head = [], [], [], []
    for a in range(n_agents):
        names, head = _names(rng, rng.randint(1, 3), f"a{a}")
        acts.append(names)
        a_head.append(head)
        names, head = _names(rng, rng.randint(1, 2), f"o{a}")
        obs.append(names)
        o_head.append(head)
    n_jo = len(list(itertools.product(*obs)))
    start = rng.choice(
        [
            "uniform",
            states[0],
            " ".join(["%.6f" % (1 / n_s)] * (n_s - 1) + ["%.6f" % (1 - (n_s - 1) * float("%.6f" % (1 / n_s)))]),
        ]
    )
    lines = [
        f"agents: {n_agents}",
        f"discount: {rng.choice([1, 0.9])}",
        f"values: {rng.choice(['reward', 'cost'])}",
        f"states: {s_head}",
        f"start: {start}",
        "actions:",
        *a_head,
        "observations:",
        *o_head,
    ]

    def state():
        return rng.choice(["*", rng.choice(states), str(rng.randrange(n_s))])

    for _ in range(rng.randint(5, 25)):
        kind, form = rng.choice("TOR"), rng.randint(0, 2)
        ja = _joint(rng, acts)
        if kind == "T":
            if form == 0:
                lines += [f"T: {ja} :", rng.choice(["uniform", "identity", _numbers(rng, n_s * n_s, n_s)])]
            elif form == 1:
                lines += [f"T: {ja} : {state()} :", rng.choice(["uniform", _numbers(rng, n_s, n_s)])]
            else:
                lines.append(f"T: {ja} : {state()} : {state()} : {round(rng.random(), 3)}")
        elif kind == "O":
            if form == 0:
                lines += [f"O: {ja} :", rng.choice(["uniform", _numbers(rng, n_s * n_jo, n_jo)])]
                if n_s == n_jo and rng.random() < 0.3:
                    lines[-1] = "identity"
            elif form == 1:
                lines += [f"O: {ja} : {state()} :", rng.choice(["uniform", _numbers(rng, n_jo, n_jo)])]
            else:
                lines.append(f"O: {ja} : {state()} : {_joint(rng, obs)} : {round(rng.random(), 3)}")
        else:
            if form == 0:
                lines += [f"R: {ja} : {state()} :", _numbers(rng, n_s * n_jo, rng.randint(1, n_jo), prob=False)]
            elif form == 1:
                lines += [f"R: {ja} : {state()} : {state()} :", _numbers(rng, n_jo, n_jo, prob=False)]
            else:
                lines.append(f"R: {ja} : {state()} : {state()} : {_joint(rng, obs)} : {rng.randint(-9, 9)}")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # regenerate the reference tables with a dense parser module
    import importlib.util
    import sys

    import numpy as np

    from decpomdp.dpomdp import problem_path

    spec = importlib.util.spec_from_file_location("old_parser", sys.argv[1])
    old = importlib.util.module_from_spec(spec)
    sys.modules["old_parser"] = old
    spec.loader.exec_module(old)
    out: dict[str, np.ndarray] = {}
    for seed in range(60):
        text = synthetic_text(seed)
        m = old.parse_dpomdp(text, check_probabilities=False)
        out[f"text_{seed}"] = np.array(text)
        for name in ("start", "transition", "observation", "reward"):
            out[f"{name}_{seed}"] = getattr(m, name)
    for problem in ["dectiger", "broadcastChannel", "recycling", "GridSmall", "oneDoor_2_7_0.20_0.00_0_2"]:
        m = old.load_dpomdp(problem_path(problem))  # oneDoor: gunzip it first for a parser without .gz support
        for name in ("start", "transition", "observation", "reward"):
            out[f"{name}_{problem}"] = getattr(m, name)
        out[f"expected_reward_{problem}"] = m.expected_reward()
    np.savez_compressed(sys.argv[2], **out)
