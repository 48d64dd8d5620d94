"""Scripts that users and ``make`` run, from the repository root: ``python tools/NAME.py``.

A script imports the module it shares with others here (``replay_timing``) as its sibling:
Python puts a script's folder first on ``sys.path``. This file makes ``tools`` a package
too, so that the analyses in ``research/`` (run as ``python -m tools.research.NAME``) import
what they share as ``tools.research.NAME``.
"""
