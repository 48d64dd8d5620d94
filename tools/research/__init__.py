"""Finished research analyses: each answered one question, written up in docs/ (see
README.md here). Run one from the repository root as ``python -m tools.research.NAME``;
what several share is imported by package path (``tools.research.v3_prior``).
"""
