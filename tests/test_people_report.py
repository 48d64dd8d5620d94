"""The report's people benchmark (eval/people_report.py), on made-up summaries."""

from __future__ import annotations

from mjexplore.eval.people_report import crowd_runs, people_lines, people_table


def _run(scene, method, seed, et, iou, end="explored", contacts=0, gap=None, stopped=None):
    metrics = {"exploration_time_s": et, "iou": iou, "end_reason": end}
    if gap is not None:
        metrics |= {"people_collisions": contacts, "people_min_distance_m": gap,
                    "time_stopped_s": stopped}
    return {"scene": scene, "method": method, "seed": seed, "metrics": metrics}


def _summaries():
    alone = [_run("office", "nearest", s, 100.0 + s, 0.84) for s in range(2)]
    ten = [_run("office", "nearest", 0, 110.0, 0.83, contacts=1, gap=0.02, stopped=3.0),
           _run("office", "nearest", 1, 121.2, 0.78, contacts=0, gap=0.05, stopped=1.0)]
    twenty = [_run("office", "nearest", 0, 150.0, 0.84, gap=0.04, stopped=6.0),
              _run("office", "nearest", 1, 101.0, 0.84, end="time_limit", gap=0.1,
                   stopped=0.0)]
    return {"people": {"runs": alone}, "people_10": {"runs": ten},
            "people_20": {"runs": twenty}}


def test_each_crowd_is_paired_with_the_same_seeds_without_people():
    header, rows = people_table(crowd_runs(_summaries()))
    by_count = {row[2]: dict(zip(header, row)) for row in rows}
    assert sorted(by_count) == [0, 10, 20]
    ten = by_count[10]
    assert ten["x no people"] == f"{(110 / 100 + 121.2 / 101) / 2:.3f}"
    assert ten["IoU change"] == f"{((0.83 - 0.84) + (0.78 - 0.84)) / 2:.4f}"
    assert ten["contacts"] == 1 and ten["least gap (m)"] == "0.020"
    assert by_count[20]["explored"] == 1 and by_count[0]["contacts"] == "-"
    # The time stood still to a tenth of a second whatever its size.
    assert ten["stood still (s)"] == "2.0 +- 1.0" and by_count[20]["stood still (s)"] == \
        "3.0 +- 3.0"


def test_the_checks_name_what_failed():
    text = "\n".join(people_lines(_summaries()))
    assert "Explored: 5 of 6 runs: not office/nearest/seed1 (time_limit)." in text
    assert "Robot-person contacts: 1 over the 4 runs among people." in text
    # Mean IoU change at 10 people is -0.035: within the bar.
    assert "within 0.05 for 1 of 1 scene and method pairs (the largest loss 0.0350" in text
    assert "20 people cost 25 % in exploration time" in text
    assert "Crowd sizes not collected yet: 5." in text


def test_no_people_summaries_no_section():
    assert people_lines({}) == []


def test_a_sweep_table_among_people_counts_contacts_and_the_least_gap():
    from mjexplore.eval.sweep import summary_table

    alone = {"end_reason": "explored", "exploration_time_s": 100.0}
    among = [alone | {"people": 10, "people_collisions": c, "people_min_distance_m": g,
                      "time_stopped_s": 2.0} for c, g in ((1, 0.05), (2, 0.02))]
    header, rows = summary_table({("office", "nearest"): among})
    row = dict(zip(header, rows[0]))
    assert row["people contacts"] == 3 and row["least gap (m)"] == "0.020"
    assert row["stood still (s)"] == "2.0 +- 0.0"
    header, rows = summary_table({("office", "nearest"): [alone]})
    assert "people contacts" not in header and len(rows[0]) == len(header)
