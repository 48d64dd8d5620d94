"""The packages import downward only: the episode engine below evaluation, the env and
training; the simulator, mapping, topology and navigation below the engine."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "mjexplore"
# What each layer may not import (anywhere in the module, lazy imports included).
ABOVE_ENGINE = {"eval", "envs", "training", "cli", "drive", "policies"}
ABOVE_CORE = ABOVE_ENGINE | {"episode", "explorers"}
FORBIDDEN = {
    "episode": ABOVE_ENGINE,
    "envs": {"eval", "training", "cli", "drive"},
    **{core: ABOVE_CORE for core in ("sim", "mapping", "topology", "navigation", "scenes",
                                     "robot", "maps", "io", "heap", "errors")},
    # The classic explorers sit below the engine (its fallback is one of them).
    **{f"explorers/{name}": ABOVE_CORE - {"explorers"}
       for name in ("base", "nearest", "potential", "rrt", "oracle", "explore_lite",
                    "frontier_tsp")},
}


def _imported_packages(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return {n.split(".")[1] for n in names if n.startswith("mjexplore.") and n.count(".") >= 1}


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_layer_imports_nothing_above_it(layer):
    target = PACKAGE / layer
    files = sorted(target.rglob("*.py")) if target.is_dir() else [target.with_suffix(".py")]
    assert files and all(f.exists() for f in files), layer
    bad = {str(f.relative_to(PACKAGE)): sorted(_imported_packages(f) & FORBIDDEN[layer])
           for f in files}
    assert not {f: b for f, b in bad.items() if b}
