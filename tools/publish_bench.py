"""Copies a sweep's tables and plots into docs/ with the command that made them.

Usage: python tools/publish_bench.py SWEEP_DIR NAME "COMMAND"
Writes docs/NAME.md (command, table, figure links) and docs/NAME/*.png|csv.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def main() -> int:
    if len(sys.argv) != 4:
        print(__doc__)
        return 2
    sweep, name, command = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    if not (sweep / "results.md").is_file():
        print(f"{sweep} has no results.md: run the sweep first.")
        return 2
    out = DOCS / name
    out.mkdir(parents=True, exist_ok=True)
    figures = sorted(sweep.glob("*.png"))
    for f in figures + [sweep / "results.csv"]:
        shutil.copy2(f, out / f.name)
    lines = [f"# {name}", "", "Made with:", "", "```bash", command, "```", "",
             (sweep / "results.md").read_text(), ""]
    lines += [f"![{f.stem}]({name}/{f.name})" for f in figures]
    (DOCS / f"{name}.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
