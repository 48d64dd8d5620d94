"""Scripts that users and ``make`` run, from the repository root: ``python tools/NAME.py``.

A script imports the modules it shares with others here (``replay_timing``,
``probe_episodes``) as its siblings: Python puts a script's folder first on ``sys.path``.
This file makes ``tools`` a package too, so that the analyses in ``research/`` (run as
``python -m tools.research.NAME``) import those modules as ``tools.NAME``.
"""
