"""The golden master of single-robot results (tools/golden_master.py, issue 50): every case
is recomputed and its hashes compared with tests/data/golden_master.json, bit for bit, so
that the "one engine" refactor can show at each step that it changed nothing."""

import importlib.util
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _load_tool():
    spec = importlib.util.spec_from_file_location(
        "golden_master", REPO / "tools" / "golden_master.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # Its dataclasses look their module up when built.
    spec.loader.exec_module(module)
    return module


gm = _load_tool()
CASES = list(gm.cases())
GOLDEN_FILE = gm.GOLDEN_PATH.relative_to(REPO)


@pytest.fixture(scope="module")
def golden() -> dict:
    """The stored golden master; skips where the platform differs from the one that wrote
    it (floating-point results may legitimately differ there)."""
    data = gm.load_golden()
    differs = gm.platform_differences(data["platform"])
    if differs:
        pytest.skip(f"{GOLDEN_FILE} was written on another platform ({'; '.join(differs)}); "
                    "its hashes are only meaningful there. To use it here, write it on this "
                    "platform from the revision before your change: python "
                    "tools/golden_master.py --write")
    return data


def failure_message(mismatch: dict) -> str:
    parts = mismatch["parts"]
    shown = ", ".join(parts[:3]) + (f" and {len(parts) - 3} more" if len(parts) > 3 else "")
    return (f"{mismatch['case']}: the hashes of {shown} differ from {GOLDEN_FILE}; its results "
            "must stay bit-identical. See every case with `python tools/golden_master.py --check` "
            f"(this one: `--only {mismatch['case']}`). Only if the change of results is "
            "intended (a change of behaviour, never a refactor), rewrite the file with "
            "`python tools/golden_master.py --write` and say why in the commit.")


def test_the_golden_master_holds_every_case_with_the_current_settings():
    # Cheap: a case or a setting changed in the tool without rewriting the file.
    data = gm.load_golden()
    assert list(data["cases"]) == CASES, (
        f"{GOLDEN_FILE} holds other cases than tools/golden_master.py computes: rewrite it "
        "with `python tools/golden_master.py --write` on the revision before any change "
        "of results.")
    assert data["settings"] == gm.settings()


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
def test_single_robot_results_are_bit_identical(name, golden):
    mismatch = gm.compare(name, golden["cases"].get(name), gm.compute_case(name))
    assert mismatch is None, failure_message(mismatch)
