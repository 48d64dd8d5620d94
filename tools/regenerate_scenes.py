"""Regenerates the canonical scenes in ``scenes_xml/`` (bit for bit from the table).

Usage:
    python tools/regenerate_scenes.py            # rewrite scenes_xml/
    python tools/regenerate_scenes.py --check    # exit 1 if any committed file differs
    python tools/regenerate_scenes.py --out DIR  # write elsewhere
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from pathlib import Path

from mjexplore.scenes.canonical import CANONICAL_SCENES, SCENES_DIR
from mjexplore.scenes.generate import generate_scene
from mjexplore.scenes.scene import write_scene


def regenerate(out: Path, names: list[str] | None = None) -> None:
    for name in names or list(CANONICAL_SCENES):
        c = CANONICAL_SCENES[name]
        write_scene(generate_scene(c.family, *c.size, seed=c.seed, name=name), out / name)


def differences(a: Path, b: Path, names: list[str]) -> list[str]:
    diffs = []
    for name in names:
        for f in sorted((a / name).iterdir()):
            other = b / name / f.name
            if not other.is_file() or not filecmp.cmp(f, other, shallow=False):
                diffs.append(f"{name}/{f.name}")
    return diffs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true")
    parser.add_argument("--out", type=Path, default=SCENES_DIR)
    parser.add_argument("names", nargs="*", help="scenes to build (default: all)")
    args = parser.parse_args()
    names = args.names or list(CANONICAL_SCENES)
    if args.check:
        with tempfile.TemporaryDirectory() as tmp:
            regenerate(Path(tmp), names)
            diffs = differences(Path(tmp), args.out, names)
        for d in diffs:
            print(f"differs: {d}")
        return 1 if diffs else 0
    regenerate(args.out, names)
    return 0


if __name__ == "__main__":
    sys.exit(main())
