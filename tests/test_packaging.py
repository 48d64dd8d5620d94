"""Runtime imports match the install: every third-party module that ``mjexplore`` (or a tool)
imports is provided by a distribution the package declares.

``mjexplore render`` once failed with ``ModuleNotFoundError: No module named 'mcap'`` on a
plain install because mcap was declared only in the test extra; this test finds such gaps
from the source (imports inside functions included) without running it.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterable
from importlib.metadata import packages_distributions
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "mjexplore"


def _normalize(name: str) -> str:
    """PEP 503 form of a distribution name (``PyYAML`` -> ``pyyaml``, ``sb3_contrib`` ->
    ``sb3-contrib``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_names(requirements: Iterable[str]) -> set[str]:
    names = set()
    for spec in requirements:
        match = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", spec)
        assert match, f"unreadable requirement {spec!r} in pyproject.toml"
        names.add(_normalize(match.group(1)))
    return names


def declared(extras: Iterable[str] = ()) -> set[str]:
    """Distributions of pyproject.toml's ``[project] dependencies`` plus the named extras."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    optional = project.get("optional-dependencies", {})
    return _requirement_names([*project["dependencies"],
                               *(r for extra in extras for r in optional[extra])])


def imported_modules(files: Iterable[Path]) -> dict[str, set[str]]:
    """Top-level names of the absolute imports in ``files`` (module level and inside
    functions alike) -> the files importing them (relative to the repository)."""
    found: dict[str, set[str]] = {}
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                modules = [node.module]
            else:
                continue
            for module in modules:
                found.setdefault(module.split(".")[0], set()).add(
                    str(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path))
    return found


def uncovered(files: Iterable[Path], allowed: set[str],
              local: frozenset[str] = frozenset()) -> dict[str, str]:
    """Third-party imports of ``files`` that no distribution in ``allowed`` provides:
    ``{module: why}``. The standard library, ``mjexplore`` and ``local`` names are skipped."""
    providers = packages_distributions()
    problems = {}
    for module, users in sorted(imported_modules(files).items()):
        if module in sys.stdlib_module_names or module == PACKAGE or module in local:
            continue
        dists = {_normalize(d) for d in providers.get(module, [])}
        if not dists:
            problems[module] = ("no installed distribution provides it (imported by "
                                f"{sorted(users)})")
        elif not dists & allowed:
            problems[module] = (f"provided by {sorted(dists)}, none of them declared (imported "
                                f"by {sorted(users)})")
    return problems


def package_files() -> list[Path]:
    return sorted((ROOT / PACKAGE).rglob("*.py"))


def tool_files() -> list[Path]:
    return sorted((ROOT / "tools").rglob("*.py"))


def test_package_imports_only_runtime_dependencies():
    problems = uncovered(package_files(), declared())
    assert not problems, ("mjexplore imports packages a plain 'pip install mjexplore' does not "
                          "install; add them to [project] dependencies in pyproject.toml: "
                          f"{problems}")


def test_tools_import_only_declared_dependencies():
    # Tools run from a checkout after 'make bench' / 'make test', which install the test extra.
    # A script's siblings (its folder is first on sys.path) and the tools package itself.
    local = {p.stem for p in tool_files()} | {"tools"}
    problems = uncovered(tool_files(), declared(["test"]), local)
    assert not problems, f"tools/ imports undeclared packages: {problems}"


def test_check_catches_an_import_declared_only_for_tests():
    # The regression this guards against: mcap listed in the test extra only.
    runtime = declared()
    assert "mcap" in runtime
    problems = uncovered(package_files(), runtime - {"mcap"})
    assert set(problems) == {"mcap"}
    assert "mjexplore/render/replay.py" in problems["mcap"]
    # And an import inside a function counts (replay.py imports mcap in a method).
    tree = ast.parse((ROOT / PACKAGE / "render" / "replay.py").read_text())
    top = {a.name.split(".")[0] for n in tree.body if isinstance(n, ast.Import) for a in n.names}
    top |= {n.module.split(".")[0] for n in tree.body
            if isinstance(n, ast.ImportFrom) and n.module}
    assert "mcap" not in top


def test_test_extras_do_not_cover_package_code(tmp_path):
    module = tmp_path / "uses_skimage.py"
    module.write_text("def f():\n    from skimage.morphology import skeletonize\n")
    assert "skimage" in uncovered([module], declared())
    assert uncovered([module], declared(["test"])) == {}


def test_a_copy_without_git_history_names_its_revision(monkeypatch):
    from mjexplore.io.provenance import git_revision

    monkeypatch.setenv("MJEXPLORE_GIT_REVISION", "c8129f1")
    assert git_revision() == "c8129f1-copy"
    monkeypatch.delenv("MJEXPLORE_GIT_REVISION")
    assert not git_revision().endswith("-copy")
