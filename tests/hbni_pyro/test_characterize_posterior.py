"""The generative planning model: characterize on a posterior simulates its posterior predictive.

Each simulated stream draws one theta from the posterior's draws, then i.i.d. outputs given it, so the
table is the mixture, over the draws, of the tables each draw gives alone.
"""

import torch

import hbni_pyro

from hbni_stubs import DrawsPosterior

DT = torch.float64


def test_a_posterior_table_is_the_mixture_of_its_draws_tables():
    """Two draws (a noisy and a clean classifier): every confusion cell and mean frame count within 5 s.e. of
    the mixture of the two single-draw tables (n = 6000 streams per class each; s.e. from all three's variances)."""
    noisy, clean = torch.tensor([0.8, 1.5, 3.0], dtype=DT), torch.tensor([6.0, 9.0, 20.0], dtype=DT)
    process = hbni_pyro.MacroObservationProcess(hbni_pyro.SSBF(3), threshold=0.9, max_frames=8)
    n = 6000
    mixed = hbni_pyro.characterize(process, DrawsPosterior(torch.stack([noisy, clean])), n, seed=0)
    a = hbni_pyro.characterize(process, noisy, n, seed=1)
    b = hbni_pyro.characterize(process, clean, n, seed=2)
    expect = 0.5 * (a.confusion + b.confusion)
    var = (mixed.confusion * (1 - mixed.confusion) + 0.25 * (a.confusion * (1 - a.confusion)
                                                               + b.confusion * (1 - b.confusion))) / n
    assert ((mixed.confusion - expect).abs() <= 5 * var.sqrt() + 1e-12).all()
    frames = 0.5 * (a.mean_frames + b.mean_frames)
    support = torch.arange(1, 9, dtype=DT)

    def frames_var(model):  # (M,) variance of frames used per class
        return model.frames_pmf @ support**2 - model.mean_frames**2

    se = ((frames_var(mixed) + 0.25 * (frames_var(a) + frames_var(b))) / n).sqrt()
    assert ((mixed.mean_frames - frames).abs() <= 5 * se).all()
    assert not torch.allclose(a.confusion, b.confusion, atol=0.05)  # the two draws do differ
    assert mixed.info["generative"] == "posterior predictive" and mixed.info["num_streams"] == n
