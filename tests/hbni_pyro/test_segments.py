"""Class names travel with the models: the posterior, its filter and process, the tables and a classified stream
check them against each other, naming the difference."""

import pytest
import torch

import hbni_pyro
from hbni_pyro import sample_outputs

NAMES = ("ambulance", "food_crate", "police_car")
THETA = torch.tensor([4.0, 6.0, 8.0], dtype=torch.float64)


@pytest.fixture(scope="module")
def posterior():
    g = torch.Generator().manual_seed(0)
    classes = torch.arange(3).repeat_interleave(10)
    return hbni_pyro.fit(
        sample_outputs(THETA, classes, g),
        classes,
        num_chains=2,
        num_samples=50,
        warmup_steps=50,
        seed=0,
        progress=False,
        class_names=NAMES,
    )


def test_names_are_stored_and_round_trip(posterior, tmp_path):
    assert posterior.class_names == NAMES
    assert hbni_pyro.HBNIPosterior.load(posterior.save(tmp_path / "p.safetensors")).class_names == NAMES
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("hbni", posterior), threshold=0.9, max_frames=4)
    assert process.class_names == NAMES
    streams = sample_outputs(
        THETA, torch.arange(3).repeat_interleave(4)[:, None].expand(12, 4), torch.Generator().manual_seed(1)
    )
    table = hbni_pyro.tabulate(process, streams, torch.arange(3).repeat_interleave(4))
    assert table.class_names == NAMES
    assert hbni_pyro.MacroObservationModel.load(table.save(tmp_path / "m.safetensors")).class_names == NAMES


def test_a_stream_in_another_class_order_is_refused(posterior):
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.make_filter("hbni", posterior), threshold=0.9, max_frames=4)
    rows = sample_outputs(THETA, torch.zeros(8, dtype=torch.long), torch.Generator().manual_seed(2))
    items = [(None, row) for row in rows]
    assert len(list(hbni_pyro.macro_observations(items, process, NAMES))) >= 2
    swapped = ("food_crate", "ambulance", "police_car")
    with pytest.raises(
        ValueError,
        match=r"classes: expected the classes of the process's posterior in its order "
        r"\['ambulance', 'food_crate', 'police_car'\].*first difference at column 0",
    ):
        next(hbni_pyro.macro_observations(items, process, swapped))


@pytest.mark.parametrize("names, error", [(("a", "b"), ValueError), (("a", "a", "b"), ValueError), ("abc", TypeError)])
def test_bad_class_names_are_refused(posterior, names, error):
    with pytest.raises(error, match="class_names"):
        hbni_pyro.fit(
            torch.full((3, 3), 1 / 3, dtype=torch.float64),
            class_names=names,
            num_samples=2,
            warmup_steps=2,
            progress=False,
        )
