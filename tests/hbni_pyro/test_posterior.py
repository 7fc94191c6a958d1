"""HBNIPosterior: summary, exact save/load round trip, corrupt and foreign files, predictive, ArviZ."""

import pickle

import pytest
import torch
from safetensors.torch import save_file

import hbni_pyro
from hbni_pyro import HBNIPosterior, sample_outputs


@pytest.fixture(scope="module")
def posterior():
    obs = sample_outputs(
        torch.tensor([1.0, 6.0, 20.0]), torch.arange(3).repeat_interleave(5), torch.Generator().manual_seed(0)
    )
    return hbni_pyro.fit(obs, num_chains=4, num_samples=200, warmup_steps=200, seed=0, progress=False)


def test_shapes_and_summary(posterior):
    assert posterior.samples["theta"].shape == (4, 200, 3)
    assert posterior.samples["kappa"].shape == posterior.samples["gamma"].shape == (4, 200)
    s = posterior.summary()
    assert set(s) == {"theta[0]", "theta[1]", "theta[2]", "kappa", "gamma"}
    for row in s.values():
        assert set(row) == {"mean", "sd", "q5", "q95", "ess", "r_hat"}
        assert row["q5"] < row["mean"] < row["q95"] and row["ess"] > 0
    assert posterior.theta_draws().shape == (800, 3)


def test_save_load_round_trip_is_exact(posterior, tmp_path):
    path = posterior.save(tmp_path / "sub" / "post.safetensors")
    back = HBNIPosterior.load(path)
    for k in posterior.samples:
        assert torch.equal(back.samples[k], posterior.samples[k])
    assert torch.equal(back.class_prior, posterior.class_prior)
    assert torch.equal(back.label_probs, posterior.label_probs)
    assert back.hyperprior == posterior.hyperprior and back.info == posterior.info
    assert not list(tmp_path.glob("sub/.*tmp")), "no temporary file is left behind"


def test_corrupt_and_foreign_files_raise_clear_errors(posterior, tmp_path):
    good = posterior.save(tmp_path / "post.safetensors").read_bytes()
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(good[: len(good) // 2])
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(b"\x00\x01not a model at all")
    pickled = tmp_path / "model.pkl"
    pickled.write_bytes(pickle.dumps({"theta": [1, 2, 3]}))
    foreign = tmp_path / "foreign.safetensors"
    save_file({"w": torch.zeros(2)}, str(foreign))
    for path in (truncated, garbage, pickled):
        with pytest.raises(ValueError, match="is not a readable model file"):
            HBNIPosterior.load(path)
    with pytest.raises(ValueError, match="holds a foreign file, expected a saved hbni_pyro.HBNIPosterior"):
        HBNIPosterior.load(foreign)
    with pytest.raises(FileNotFoundError, match="no such file"):
        HBNIPosterior.load(tmp_path / "missing.safetensors")


def test_posterior_predictive_outputs(posterior):
    a = posterior.sample_outputs(2, 5000, seed=1)
    assert a.shape == (5000, 3) and torch.equal(a, posterior.sample_outputs(2, 5000, seed=1))
    torch.testing.assert_close(a.sum(-1), torch.ones(5000, dtype=torch.float64))
    # E[o_m | c = m] = E[(theta_m + 1) / (theta_m + M)] over the posterior; 5 standard errors.
    theta = posterior.theta_draws()[:, 2]
    expected = ((theta + 1) / (theta + 3)).mean()
    assert abs(a[:, 2].mean() - expected) < 5 * a[:, 2].std() / 5000**0.5
    with pytest.raises(ValueError, match="true_class"):
        posterior.sample_outputs(3, 10)
    with pytest.raises(ValueError, match="n: expected"):
        posterior.sample_outputs(0, 0)


def test_to_arviz(posterior):
    pytest.importorskip("arviz")
    idata = posterior.to_arviz()
    assert idata.posterior["theta"].shape == (4, 200, 3)


def test_bad_construction_and_point_estimates(posterior):
    with pytest.raises(ValueError, match="missing sites"):
        HBNIPosterior({"theta": torch.ones(1, 2, 3)}, torch.ones(3) / 3)
    with pytest.raises(ValueError, match=r"samples\['kappa'\]"):
        HBNIPosterior(
            {"theta": torch.ones(1, 2, 3), "kappa": torch.ones(2), "gamma": torch.ones(1, 2)}, torch.ones(3) / 3
        )
    with pytest.raises(ValueError, match="estimate"):
        posterior.theta_point("mode")
    assert posterior.theta_point("median").shape == (3,)
