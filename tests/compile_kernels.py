"""Compile the project's numba kernels into their on-disk cache (``hbni_infra.numba_cache``), one part per process.

``tests/conftest.py`` runs both parts side by side before the suite's workers start. On a fresh machine each
worker would otherwise compile every kernel it meets, several workers the same kernel at once (package
delivery's event loop alone takes about 30 s). Where the cache is warm, a part only loads it.

    python tests/compile_kernels.py package_delivery|others
"""

from __future__ import annotations

import sys

import torch


def package_delivery() -> None:
    from decpomdp import simulate
    from decpomdp.domains import PackageDelivery, package_delivery

    simulate(PackageDelivery(), package_delivery.greedy_controller(), 2, torch.Generator().manual_seed(0))


def others() -> None:
    """Disaster relief's and the tabular problems' event loops, the MH class move and the sequence model's loops
    (its sampler's and its filter's evidence)."""
    import hbni_pyro
    from decpomdp import JointController, simulate
    from decpomdp.domains import DisasterRelief, disaster_relief
    from decpomdp.dpomdp import load_problem
    from decpomdp.dpomdp.tabular import TabularDecPOSMDP
    from hbni_pyro import sample_outputs

    g = torch.Generator().manual_seed(0)
    simulate(DisasterRelief(), disaster_relief.greedy_controller(), 2, g)
    tiger = TabularDecPOSMDP(load_problem("dectiger"), horizon=3)
    listen = JointController(torch.zeros(1, 2, 1, dtype=torch.long), torch.zeros(1, 2, 1, 2, dtype=torch.long))
    simulate(tiger, listen, 2, g)
    obs = sample_outputs(torch.tensor([2.0, 5.0, 9.0]), torch.arange(3).repeat_interleave(4), g)
    settings = dict(num_chains=2, num_samples=2, warmup_steps=2, progress=False)
    hbni_pyro.fit(obs, **settings)
    posterior = hbni_pyro.fit(
        obs, torch.arange(3).repeat_interleave(4), model="sequence", sequence_ids=torch.arange(12) // 2, **settings
    )
    hbni_pyro.HBNIFilter(posterior).run(obs.view(3, 4, 3))  # the sequence model's compiled evidence


if __name__ == "__main__":
    {"package_delivery": package_delivery, "others": others}[sys.argv[1]]()
