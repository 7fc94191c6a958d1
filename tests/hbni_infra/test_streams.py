"""Named random streams: distinct by name, reproducible, and no ``seed + N`` arithmetic anywhere."""

import re
from pathlib import Path

import pytest
import torch

from hbni_infra.streams import numpy_stream, stream_seed, torch_stream

ROOT = Path(__file__).resolve().parents[2]


def test_streams_are_reproducible_and_distinct_by_name():
    names = [
        ("plan", "hbni"),
        ("plan", "ssbf"),
        ("score", "hbni"),
        ("greedy", "hbni"),
        ("bank",),
        ("replicate", 0),
        ("replicate", 1),
        ("replicate", "1"),
        (),
    ]
    seeds = [stream_seed(0, *n) for n in names] + [stream_seed(1, *n) for n in names]
    assert len(set(seeds)) == len(seeds)  # no two stages or variants share a stream
    assert all(0 <= s < 2**62 for s in seeds)
    assert stream_seed(0, "plan", "hbni") == stream_seed(0, "plan", "hbni")
    a, b = torch_stream(3, "x"), torch_stream(3, "y")
    assert not torch.equal(torch.rand(8, generator=a), torch.rand(8, generator=b))
    assert torch.equal(torch.rand(8, generator=torch_stream(3, "x")), torch.rand(8, generator=torch_stream(3, "x")))
    assert numpy_stream(3, "x").integers(1 << 30) == numpy_stream(3, "x").integers(1 << 30)


def test_streams_of_one_seed_are_uncorrelated():
    draws = torch.stack(
        [torch.rand(4000, generator=torch_stream(7, "variant", k), dtype=torch.float64) for k in range(6)]
    )
    corr = torch.corrcoef(draws)
    off = corr[~torch.eye(6, dtype=torch.bool)]
    assert off.abs().max() < 4 / 4000**0.5  # 4 standard errors of a zero correlation


@pytest.mark.parametrize("bad", [-1, 1.5, "0", True])
def test_bad_seeds_and_names(bad):
    with pytest.raises((ValueError, TypeError)):
        stream_seed(bad, "x")
    with pytest.raises(TypeError, match="names"):
        stream_seed(0, 1.5)


def test_no_seed_arithmetic_in_the_code():
    pattern = re.compile(r"\bseed(_\w*|s)?\)*\s*[-+*]\s*[\w(]|[\w)]\s*[+*]\s*\w*seed\b")
    hashes = {ROOT / "hbni_infra" / "counter_random.py"}  # the counter-based generator: seeds are hashed there
    hits = []
    for folder in ("hbni_pyro", "classifiers", "decpomdp", "experiments", "benchmarks", "hbni_infra"):
        for path in set((ROOT / folder).rglob("*.py")) - hashes:
            for number, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#")[0]
                if pattern.search(code) and "stream_seed" not in code:
                    hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not hits, "seeds by arithmetic:\n" + "\n".join(hits)
