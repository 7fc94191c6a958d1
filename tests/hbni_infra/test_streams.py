"""Named random streams: distinct by name, reproducible, and no ``seed + N`` arithmetic anywhere; generators are
seeded only in ``hbni_infra.streams``."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

from hbni_infra.streams import numpy_generator, numpy_stream, stream_seed, torch_generator, torch_stream

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


def test_generators_of_a_seed_as_given():
    # the independent references: torch's and numpy's own seeding
    assert torch.equal(
        torch.rand(8, generator=torch_generator(5)), torch.rand(8, generator=torch.Generator().manual_seed(5))
    )
    big = 2**63 - 1
    assert torch.equal(
        torch.rand(4, generator=torch_generator(big)), torch.rand(4, generator=torch.Generator().manual_seed(big))
    )
    assert torch_generator(np.int64(5)).initial_seed() == 5 and torch_generator(3, "cpu").device == torch.device("cpu")
    assert torch_generator(0, torch.device("meta")) is None  # shapes only: nothing is drawn on meta
    assert numpy_generator(5).random() == np.random.default_rng(5).random()
    assert numpy_generator(2**40).random() == np.random.default_rng(2**40).random()
    assert (
        numpy_generator(5, 2, 7).integers(1 << 30, size=4) == np.random.default_rng([5, 2, 7]).integers(1 << 30, size=4)
    ).all()


@pytest.mark.parametrize("bad", [-1, 2**63, 1.5, "0", True, None])
def test_generators_refuse_bad_seeds(bad):
    with pytest.raises((TypeError, ValueError), match="seed"):
        torch_generator(bad)
    with pytest.raises((TypeError, ValueError), match="entropy"):
        numpy_generator(0, bad)
    with pytest.raises(ValueError, match="entropy"):
        numpy_generator()


SEEDINGS = re.compile(r"manual_seed|np\.random\.seed|default_rng|SeedSequence|random\.Random\(|\brandom\.seed\(")


def test_generators_are_seeded_only_in_the_stream_helper():
    """The shipped code and the benchmarks seed through ``hbni_infra.streams`` (the tests and the docs' examples
    seed with torch's own ``torch.Generator().manual_seed``, as a user does)."""
    helper = ROOT / "hbni_infra" / "streams.py"
    hits = []
    for folder in ("hbni_pyro", "classifiers", "decpomdp", "experiments", "hbni_infra", "benchmarks", "scripts"):
        for path in sorted(set((ROOT / folder).rglob("*.py")) - {helper}):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if SEEDINGS.search(line.split("#")[0]):
                    hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not hits, "generators seeded outside hbni_infra.streams:\n" + "\n".join(hits)
