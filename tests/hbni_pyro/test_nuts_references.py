"""The stored NUTS references: written from the problems and settings they name, and refused once the model
they were drawn from has changed."""

import json

import pytest
import torch

import nuts_references
from known_models import DT


@pytest.mark.parametrize("name", list(nuts_references.SETTINGS))
def test_each_reference_holds_its_problem_and_settings(name):
    ref = nuts_references.load_reference(name)
    problem = nuts_references.problems()[name]
    assert ref.problem.model == problem.model and ref.settings == nuts_references.SETTINGS[name]
    torch.testing.assert_close(ref.problem.obs, problem.obs.to(DT), rtol=1e-12, atol=0)
    for stored, now in ((ref.problem.labels, problem.labels), (ref.problem.sequence_ids, problem.sequence_ids)):
        assert (stored is None and now is None) or torch.equal(stored, now)
    draws = ref.settings["num_chains"] * ref.settings["num_samples"]
    assert all(0 < s["ess"] <= 2 * draws and s["sd"] > 0 for s in ref.summary.values())
    torch.testing.assert_close(ref.label_probs.sum(-1), torch.ones(len(problem.obs), dtype=DT))


def test_a_reference_whose_model_changed_is_refused(tmp_path, monkeypatch):
    entries = json.loads(nuts_references.PATH.read_text())
    entries["toy"]["potentials"][2] *= 1 + 1e-6
    changed = tmp_path / "nuts_references.json"
    changed.write_text(json.dumps(entries))
    monkeypatch.setattr(nuts_references, "PATH", changed)
    with pytest.raises(AssertionError, match="'toy' model's potential energy changed.*nuts_references.py toy"):
        nuts_references.load_reference("toy")
    nuts_references.load_reference("sequence")  # the others still load


def test_the_script_refuses_an_unknown_name(tmp_path, monkeypatch):
    monkeypatch.setattr(nuts_references, "PATH", tmp_path / "refs.json")
    with pytest.raises(SystemExit, match="expected names from \\['toy', 'confusion', 'sequence'\\], got 'nope'"):
        nuts_references.main(["nope"])
    assert not (tmp_path / "refs.json").exists()
