"""One-file tensor storage: round trip, kinds, corrupt, foreign, legacy and directory inputs."""

import json

import pytest
import torch
from safetensors.torch import save as st_save

from hbni_infra.tensorfile import load_tensors, save_tensors, seal


def test_round_trip_is_exact_and_copies(tmp_path):
    tensors = {"a": torch.randn(3, 4, dtype=torch.float64), "b": torch.arange(5)}
    path = save_tensors(tmp_path / "m.safetensors", "pkg.Thing", tensors, {"version": 1, "x": [1, 2]})
    back, meta = load_tensors(path, "pkg.Thing")
    assert meta == {"version": 1, "x": [1, 2]}
    assert set(back) == {"a", "b"} and all(torch.equal(back[k], tensors[k]) for k in tensors)
    back["a"].zero_()  # the loaded tensors are writable copies
    assert not torch.equal(load_tensors(path, "pkg.Thing")[0]["a"], back["a"])


def test_another_kind_is_refused_by_name(tmp_path):
    path = save_tensors(tmp_path / "m.safetensors", "pkg.Thing", {"a": torch.zeros(1)}, {})
    with pytest.raises(ValueError, match="holds pkg.Thing, expected a saved pkg.Other"):
        load_tensors(path, "pkg.Other")


@pytest.mark.parametrize("content", [b"", b"\x00" * 40, b"\xff" * 7, b"not a model at all, just text"])
def test_corrupt_files_are_clear_errors(tmp_path, content):
    path = tmp_path / "bad.safetensors"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="is not a readable model file"):
        load_tensors(path, "pkg.Thing")


def test_foreign_safetensors_and_bad_metadata(tmp_path):
    foreign = tmp_path / "foreign.safetensors"
    foreign.write_bytes(st_save({"w": torch.zeros(2)}))
    with pytest.raises(ValueError, match="holds a foreign file, expected a saved pkg.Thing"):
        load_tensors(foreign, "pkg.Thing")
    broken = tmp_path / "broken.safetensors"
    broken.write_bytes(st_save({"w": torch.zeros(2)}, metadata={"kind": "pkg.Thing", "metadata": "{not json"}))
    with pytest.raises(ValueError, match="corrupt metadata"):
        load_tensors(broken, "pkg.Thing")
    listed = tmp_path / "listed.safetensors"
    listed.write_bytes(st_save({"w": torch.zeros(2)}, metadata={"kind": "pkg.Thing", "metadata": json.dumps([1])}))
    with pytest.raises(ValueError, match="not a JSON object"):
        load_tensors(listed, "pkg.Thing")


def test_files_without_a_digest_are_refused_until_sealed_in_either_layout(tmp_path):
    old = tmp_path / "old.safetensors"
    header = {"hbni_pyro.kind": "HBNIPosterior", "hbni_pyro.metadata": json.dumps({"version": 1})}
    old.write_bytes(st_save({"theta": torch.ones(2)}, metadata=header))
    with pytest.raises(ValueError, match=r"old.safetensors' has no digest .*seal\("):
        load_tensors(old, "hbni_pyro.HBNIPosterior")
    seal(old, "hbni_pyro.HBNIPosterior")
    tensors, meta = load_tensors(old, "hbni_pyro.HBNIPosterior")
    assert meta == {"version": 1} and torch.equal(tensors["theta"], torch.ones(2))
    older = tmp_path / "older.safetensors"
    header = {"decpomdp.kind": "decpomdp.JointController", "decpomdp.metadata": json.dumps({"version": 1})}
    older.write_bytes(st_save({"action": torch.zeros(1)}, metadata=header))
    with pytest.raises(ValueError, match="holds decpomdp.JointController, expected a saved pkg.Thing"):
        seal(older, "pkg.Thing")
    seal(older, "decpomdp.JointController")
    assert load_tensors(older, "decpomdp.JointController")[1] == {"version": 1}


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        load_tensors(tmp_path / "missing.safetensors", "pkg.Thing")
    with pytest.raises(IsADirectoryError, match="is a directory, expected a saved pkg.Thing file"):
        load_tensors(tmp_path, "pkg.Thing")


def test_every_file_records_its_format_version_and_another_is_refused(tmp_path):
    path = save_tensors(tmp_path / "v.safetensors", "pkg.Thing", {"x": torch.ones(1)}, {}, version=3)
    assert load_tensors(path, "pkg.Thing", version=3)[1] == {"version": 3}
    with pytest.raises(
        ValueError,
        match="format version 3 of a saved pkg.Thing; this version of the package reads "
        r"version 2 \(the file comes from a newer release: upgrade the package\)",
    ):
        load_tensors(path, "pkg.Thing", version=2)
    with pytest.raises(ValueError, match="reads version 4$"):
        load_tensors(path, "pkg.Thing", version=4)
