"""JointController validation, indexing and save/load round trip with corrupt-file errors."""

import pytest
import torch

from decpomdp import JointController, random_controllers


def make(k=3, a=2, nn=4, m=5, o=3, seed=0):
    return random_controllers(
        k, num_agents=a, num_nodes=nn, num_actions=m, num_obs=o, generator=torch.Generator().manual_seed(seed)
    )


def test_round_trip(tmp_path):
    c = make()
    path = c.save(tmp_path / "sub" / "ctrl.safetensors")
    back = JointController.load(path)
    assert torch.equal(back.action, c.action) and torch.equal(back.next_node, c.next_node)
    assert (back.num_controllers, back.num_agents, back.num_nodes, back.num_obs) == (3, 2, 4, 3)
    assert [p.name for p in path.parent.iterdir()] == ["ctrl.safetensors"]  # no temporary file left behind


def test_corrupt_and_foreign_files(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00garbage that is not a safetensors file")
    with pytest.raises(ValueError, match="is not a readable model file"):
        JointController.load(bad)
    from safetensors.torch import save_file

    foreign = tmp_path / "foreign.safetensors"
    save_file({"action": torch.zeros(1, 2, 3, dtype=torch.long)}, str(foreign))
    with pytest.raises(ValueError, match="holds a foreign file, expected a saved decpomdp.JointController"):
        JointController.load(foreign)
    truncated = tmp_path / "trunc.safetensors"
    truncated.write_bytes(make().save(tmp_path / "ok.safetensors").read_bytes()[:-7])
    with pytest.raises(ValueError, match="is not a readable model file"):
        JointController.load(truncated)
    with pytest.raises(FileNotFoundError, match="path"):
        JointController.load(tmp_path / "missing.safetensors")


def test_indexing_and_cat():
    c = make(k=4)
    assert c[2].num_controllers == 1 and torch.equal(c[2].action[0], c.action[2])
    assert torch.equal(c[-1].action, c.action[-1:])
    assert torch.equal(JointController.cat([c[:2], c[2:]]).next_node, c.next_node)


def test_validation():
    with pytest.raises(TypeError, match="action"):
        JointController(torch.zeros(1, 2, 3), torch.zeros(1, 2, 3, 2, dtype=torch.long))
    with pytest.raises(ValueError, match="action: expected shape"):
        JointController(torch.zeros(2, 3, dtype=torch.long), torch.zeros(1, 2, 3, 2, dtype=torch.long))
    with pytest.raises(ValueError, match="next_node: expected shape"):
        JointController(torch.zeros(1, 2, 3, dtype=torch.long), torch.zeros(1, 2, 4, 2, dtype=torch.long))
    with pytest.raises(ValueError, match=r"next_node: entries must lie in \[0, 3\)"):
        JointController(torch.zeros(1, 2, 3, dtype=torch.long), torch.full((1, 2, 3, 2), 3, dtype=torch.long))
    with pytest.raises(ValueError, match="action: entries must be >= 0"):
        JointController(-torch.ones(1, 2, 3, dtype=torch.long), torch.zeros(1, 2, 3, 2, dtype=torch.long))
    with pytest.raises(ValueError, match="count"):
        make(k=0)
