"""Evaluation: episodes, metrics over time, sweeps, tables and plots."""
