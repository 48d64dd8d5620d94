"""One explorer per method; policies are models that --policy picks; run labels of the
report's runs (gvn_v3, gvn_naive, the paper's recipe as gvn ...) still name their setting."""

import json

import pytest

from mjexplore.cli import build_parser, main
from mjexplore.errors import UserInputError
from mjexplore.eval.methods import LEARNED, METHODS, MethodSpec, parse_method
from mjexplore.explorers import CLASSIC
from mjexplore.policies.models import DEFAULT_MODEL, shipped_models


def test_every_method_is_a_classic_or_a_learned_explorer():
    assert set(METHODS) == set(CLASSIC) | set(LEARNED)
    assert set(DEFAULT_MODEL) == set(LEARNED)
    assert all(shipped_models()[m].kind == k for k, m in DEFAULT_MODEL.items())


def test_help_lists_one_name_per_method():
    explore = build_parser()._subparsers._group_actions[0].choices["explore"]
    text = explore.format_help()
    assert "gvn_v3" not in text.split("--policy")[0]  # Models are not explorer names.
    listed = text.split("one of:")[1]
    assert all(f"{name}:" in listed for name in METHODS)
    assert not set(METHODS) & set(shipped_models())  # Explorers and ablations, not models.


@pytest.mark.parametrize("name", sorted(shipped_models()))
def test_run_labels_and_specs_name_the_same_setting(name):
    model = shipped_models()[name]
    for masking in (None, False):
        spec = MethodSpec(model.kind, name, masking)
        again = parse_method(spec.text)
        assert (again.method, again.policy) == (model.kind, name)
        if spec.label in LEARNED:
            continue  # The paper's label 'gvn' is also the method: sweeps carry spec.text.
        by_label = parse_method(spec.label)
        assert by_label.label == spec.label and by_label.policy == name


def test_legacy_labels_of_the_report():
    assert parse_method("gvn_v3") == MethodSpec("gvn", "gvn_v3", True)
    assert parse_method("gvn_unmasked") == MethodSpec("gvn", "gvn_paper", False)
    assert parse_method("gvn_v3_none").policy == "gvn_v3_none"
    assert MethodSpec("gvn", "gvn_paper").label == "gvn"  # The paper's runs' label.
    assert parse_method("gvn") == MethodSpec("gvn")  # The method: its default model.
    assert parse_method("gvn").label == "gvn_v3"
    with pytest.raises(UserInputError, match="only the learned"):
        parse_method("nearest:gvn_v3")


def test_policy_picks_the_model_and_the_run_records_it(tmp_path):
    out = tmp_path / "o"
    assert main(["explore", "--scene", "train_loop", "--explorer", "gvn", "--policy",
                 "gvn_paper", "--max-time", "3", "--no-mcap", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["policy"] == "gvn_paper" and metrics["explorer"] == "gvn"
    assert metrics["weights_sha256"].startswith("1a64c4fef1f6bc4b")


def test_policy_on_a_classic_explorer_is_refused(tmp_path, capsys):
    assert main(["explore", "--explorer", "nearest", "--policy", "gvn_v3",
                 "--out", str(tmp_path / "o")]) == 2
    assert "learned explorers only" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
