"""The house reads one way: the import contracts of pyproject.toml hold (each layer imports
only the layers below it; no import cycle between the modules of a package), ruff finds
nothing, and the package type-checks (mypy). All run as `make test` runs, from the
repository root."""

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _tool(name: str) -> str:
    path = BIN / name
    found = str(path) if path.exists() else shutil.which(name)
    if found is None:
        pytest.fail(f"{name} is not installed: run 'make test' (it installs the test extras).")
    return found


def test_import_contracts_hold():
    r = subprocess.run([_tool("lint-imports"), "--no-cache"], cwd=REPO, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "2 kept, 0 broken" in r.stdout


def test_a_climbing_import_breaks_the_layers_contract(tmp_path):
    # The contract bites: a copy of the package where the episode engine imports evaluation.
    package = tmp_path / "mjexplore"
    shutil.copytree(REPO / "mjexplore", package, ignore=shutil.ignore_patterns("__pycache__"))
    (package / "episode" / "climb.py").write_text("import mjexplore.eval.run  # noqa: F401\n")
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    r = subprocess.run([_tool("lint-imports"), "--no-cache"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120, env={"PYTHONPATH": str(tmp_path), "PATH": ""})
    assert r.returncode == 1 and "mjexplore.episode.climb -> mjexplore.eval.run" in r.stdout


@pytest.mark.slow
def test_mypy_finds_nothing_in_the_package():
    """The package type-checks (pyproject.toml [tool.mypy]); its cache goes to a temporary
    folder, so each run checks everything."""
    with tempfile.TemporaryDirectory() as cache:
        r = subprocess.run([sys.executable, "-m", "mypy", "--cache-dir", cache], cwd=REPO,
                           capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:]


def test_ruff_finds_nothing():
    r = subprocess.run([_tool("ruff"), "check", "--no-cache", "."], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-3000:]
