"""The report's multi-robot sections: a team sweep collected and reported, with the single
robot beside, issue 37's bars and every run's revision."""

from __future__ import annotations

import json

from mjexplore.cli import main
from mjexplore.eval.team_report import office_verdict, pair_verdict


def test_a_team_sweep_is_collected_and_reported(tmp_path):
    out, data = tmp_path / "bench", tmp_path / "data"
    assert main(["bench", "--scenes", "train_loop", "--robots", "2", "--explorers",
                 "assign_greedy,nearest", "--seeds", "1", "--workers", "1", "--max-time", "8",
                 "--no-progress", "--out", str(out)]) == 0
    assert main(["collect", str(out), "--experiment", "teams", "--data", str(data)]) == 0
    summary = json.loads((data / "teams.json").read_text())
    methods = {r["method"] for r in summary["runs"]}
    assert methods == {"nearest x1 single", "assign_greedy x2 drawn", "nearest x2 drawn"}
    assert all(r["revision"] for r in summary["runs"])
    report = tmp_path / "results.md"
    assert main(["report", "--data", str(data), "--out", str(report)]) == 0
    text = report.read_text()
    section = text[text.index("## Several robots: the evaluation scenes"):]
    assert "| train_loop | - | single nearest | 1 | 1 |" in section
    assert "| train_loop | drawn | assign_greedy | 2 | 1 |" in section
    assert "| train_loop | drawn | naive_nearest | 2 | 1 |" in section
    assert "Every run was made at revision" in section


def _m(t985, overlap=0.3, **kw):
    return {"t985_s": t985, "overlap_ratio": overlap, "end_reason": "explored",
            "robot_collisions": 0, "collisions": 0, **kw}


def test_the_bars_are_checked():
    single = {("office", 0): _m(800.0), ("office", 1): _m(1000.0)}
    groups = {("office", "drawn", "assign_greedy", 2): [(0, _m(400.0)), (1, _m(520.0))],
              ("office", "drawn", "naive_nearest", 2): [(0, _m(300.0)), (1, _m(300.0))],
              ("office", "drawn", "assign_greedy", 3): [(0, _m(400.0)), (1, _m(500.0))],
              ("office", "drawn", "assign_greedy+unknown", 2): [
                  (0, _m(450.0, merged=True, merge_time_s=10.0, merge_error_m=0.02,
                         merge_error_deg=0.1)),
                  (1, _m(None, merged=False, merge_error_m=None, merge_error_deg=None))]}
    lines = office_verdict(single, groups)
    # The naive team does not count as coordination, however fast.
    assert "assign_greedy, took 0.510" in lines[0] and "met" in lines[0]
    assert "0.500" in lines[1] and "NOT met" in lines[1]
    assert "1 of 2 runs merged" in lines[2] and "1 within" in lines[2]
    pairs = {("room", "far", "assign_greedy", 2): [(0, _m(50.0, 0.2))],
             ("room", "far", "naive_nearest", 2): [(0, _m(60.0, 0.3))],
             ("loop", "far", "assign_greedy", 2): [(0, _m(70.0, 0.2))],
             ("loop", "far", "naive_nearest", 2): [(0, _m(65.0, 0.1))]}
    assert "faster on 1 of 2" in pair_verdict(pairs)[0]
    assert "does NOT beat" in pair_verdict(pairs)[0]
