"""``mjexplore probe-policy`` (mjexplore/eval/probe.py: :func:`probe_policy`): a shipped
policy beside random choices on one episode of its training env, and bad input refused
with exit status 2 and a one-line message saying how to fix it, before any episode runs."""

from __future__ import annotations

import json

import pytest

from mjexplore.cli import main
from mjexplore.errors import UserInputError
from mjexplore.eval.probe import probe_policy
from mjexplore.policies.models import MODELS_DIR

REPO = MODELS_DIR.parent
GVN_V3 = str(MODELS_DIR / "gvn_v3" / "policy.safetensors")
CNN = str(MODELS_DIR / "cnn_paper" / "policy.safetensors")


def test_one_episode_prints_one_json_line_of_figures(capsys):
    # About 13 s on 2 cores: the grid world of gvn_v3's training env, two episodes.
    argv = ["probe-policy", "--weights", GVN_V3, "--episodes", "1", "--modes", "policy,random",
            "--workers", "1"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1, out
    figures = json.loads(out)
    assert figures["episodes"] == 1
    assert figures["config"] == "stored with the weights"
    assert figures["layouts"] == "seeds from 10000"
    for mode in ("policy", "random"):
        assert isinstance(figures[f"{mode}_return"], float)
        assert figures[f"{mode}_exploration_time_s"] > 0
        assert figures[f"{mode}_path_length_m"] > 0
        assert figures[f"{mode}_explored"] in (0, 1)
    # Without greedy there is no scale to place the policy on.
    assert "learned_fraction" not in figures and "policy_over_greedy_time" not in figures


@pytest.mark.parametrize(("extra", "says"), [
    (["--modes", "polcy,random"], ["unknown mode 'polcy'", "policy, random, greedy, prior"]),
    (["--modes", "policy,nearest"], ["explorer modes (nearest) need --heldout or --unseen"]),
    (["--modes", ","], ["--modes takes policy, random, greedy, prior"]),
    (["--modes", "prior", "--weights", CNN, "--config",
      str(REPO / "training" / "cnn.yaml")],
     ["--modes prior needs a GVN with v2 or v3", "is a cnn policy", "drop prior from --modes"]),
    (["--weights", "no/such/policy.safetensors"], ["no/such/policy.safetensors"]),
])
def test_bad_input_exits_2_with_one_line_saying_how_to_fix(capsys, extra, says):
    argv = ["probe-policy", "--weights", GVN_V3, "--episodes", "1", *extra]
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("mjexplore probe-policy: error: "), captured.err
    assert captured.err.count("\n") == 1, captured.err
    for text in says:
        assert text in captured.err, captured.err


@pytest.mark.parametrize("extra", [["--episodes", "0"], ["--unseen", "-1"],
                                   ["--workers", "0"], ["--seed-base", "-5"]])
def test_counts_out_of_range_are_argument_errors(capsys, extra):
    with pytest.raises(SystemExit) as exit_:
        main(["probe-policy", "--weights", GVN_V3, *extra])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert extra[0] in err and extra[1] in err, err


@pytest.mark.parametrize(("kwargs", "says"), [
    ({"episodes": 0}, "--episodes 0 must be a whole number >= 1"),
    ({"unseen": -1}, "--unseen -1 must be a whole number >= 0"),
    ({"workers": 0}, "--workers 0 must be a whole number >= 1"),
    ({"modes": ("random", "oracle")}, "need --heldout or --unseen"),
])
def test_the_library_function_checks_its_arguments_too(kwargs, says):
    with pytest.raises(UserInputError, match=says):
        probe_policy(GVN_V3, **kwargs)


def test_probe_policy_help_names_every_option(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["probe-policy", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    for option in ("--config", "--weights", "--episodes", "--seed-base", "--heldout",
                   "--unseen", "--modes", "--workers"):
        assert option in text
