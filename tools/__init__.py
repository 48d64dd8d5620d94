"""Scripts that users and ``make`` run, from the repository root: ``python tools/NAME.py``.

A script keeps what its measurements share inside itself (related benchmarks are one script
with subcommands, ``bench_replay.py``), so none imports a sibling. This file makes ``tools``
a package, so that the analyses in ``research/`` (run as ``python -m tools.research.NAME``)
import what they share as ``tools.research.NAME``.
"""
