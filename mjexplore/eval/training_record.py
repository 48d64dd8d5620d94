"""Training runs in the results report: what is kept of a run, and the report's section on it.

``mjexplore collect-training RUN`` keeps, in ``DATA/training/NAME/`` beside the sweep
summaries (a few tens of kB; no weights):

* ``eval.csv``: the run's validation evaluations (one row per layout per evaluation);
* ``baselines.json``: ``pocket_nearest`` (the prior alone) and the ``oracle`` measured on
  the same validation layouts with the same settings (``mjexplore plot-training`` measures
  and caches them in the run folder);
* ``config.yaml``: the resolved recipe, its first line the revision the run started at;
* ``facts.json``: :func:`~mjexplore.eval.learning_curve.run_facts` (decisions trained; each
  start or resume's host, cores, device, revision, steps and wall time), and the shipped
  policy's departures from its prior when ``RUN/departures.json`` exists
  (``mjexplore plot-training --departures`` writes it).

:func:`training_section` turns each kept run into the report's learning curve, its table of
evaluations paired per layout against ``pocket_nearest``, and the budget it took.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from mjexplore.errors import UserInputError
from mjexplore.io.atomic import write_bytes_atomic, write_text_atomic

TRAINING_DIR = "training"  # Below the report's data folder.
KEPT_FILES = ("eval.csv", "baselines.json", "config.yaml")
FACTS_FILE = "facts.json"
DEPARTURES_FILE = "departures.json"


def collect_training(run: str | Path, data_dir: str | Path, name: str | None = None) -> Path:
    """Keeps a training run's record for the report (see the module docstring).

    Args:
        run: A run folder of ``mjexplore train --out`` with at least one evaluation.
        data_dir: The report's data folder (``docs/results/data``).
        name: The record's name (default: the run folder's name).

    Returns:
        The record's folder.

    Raises:
        UserInputError: ``run`` has no evaluations, or ``name`` is not a plain name.
    """
    from mjexplore.eval.learning_curve import read_evaluations, run_facts

    run = Path(run)
    if not (run / "eval.csv").is_file():
        raise UserInputError(f"{str(run)!r} holds no eval.csv: give a run folder of "
                             "'mjexplore train --out' once it has evaluated (eval.every).")
    if not read_evaluations(run):  # Also refuses a damaged one, before anything is kept.
        raise UserInputError(f"{str(run / 'eval.csv')!r} holds no evaluation yet: collect the "
                             "run once it has evaluated (eval.every).")
    name = name or run.resolve().name
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or name.startswith("."):
        raise UserInputError(f"--name {name!r}: use letters, digits, '_', '-' and '.' (it "
                             "names the record's folder).")
    dest = Path(data_dir) / TRAINING_DIR / name
    dest.mkdir(parents=True, exist_ok=True)
    for file in KEPT_FILES:
        if (run / file).is_file():
            write_bytes_atomic(dest / file, (run / file).read_bytes())
        else:
            (dest / file).unlink(missing_ok=True)  # Not this run's: no stale copy.
    facts = run_facts(run)
    if (run / DEPARTURES_FILE).is_file():
        facts["departures"] = json.loads((run / DEPARTURES_FILE).read_text())
    write_text_atomic(dest / FACTS_FILE, json.dumps(facts, indent=1) + "\n")
    return dest


def record_baselines(record: Path, layouts: set[str]) -> dict[str, list[dict[str, Any]]]:
    """The baselines kept with a record that were measured on exactly ``layouts`` (the
    last such entry of ``baselines.json``): per baseline, its per-layout figures; {} if
    none."""
    path = record / "baselines.json"
    if not path.is_file():
        return {}
    from mjexplore.eval.learning_curve import BASELINES

    found: dict[str, list[dict[str, Any]]] = {}
    for entry in json.loads(path.read_text()).get("entries", {}).values():
        if set(entry["key"]["layouts"]) == layouts:
            found = {name: entry[name] for name in BASELINES if entry.get(name)}
    return found


def _sessions_line(facts: dict[str, Any]) -> str:
    sessions = facts.get("sessions") or []
    if not sessions:
        return "The run records no sessions (it predates sessions.json)."
    hours = sum(s.get("wall_s", 0.0) for s in sessions) / 3600
    cores = sorted({s["cores"] for s in sessions if s.get("cores")})
    devices = sorted({s["device"] for s in sessions if s.get("device")})
    revisions = list(dict.fromkeys(s["revision"][:7] for s in sessions if s.get("revision")))
    count = f"{len(sessions)} sessions (start and resumes)" if len(sessions) > 1 else \
        "1 session"
    return (f"{count}: {hours:.1f} h of wall time on "
            f"{' or '.join(map(str, cores))} cores ({', '.join(devices)}), at revision"
            f"{'s' if len(revisions) > 1 else ''} {', '.join(f'`{r}`' for r in revisions)}.")


def _ratio_cells(paired: dict[str, Any] | None) -> list[str]:
    if paired is None:
        return ["-", "-", "-"]
    return [f"{paired['ratio']:.3f} ({paired['ci95'][0]:.3f}-{paired['ci95'][1]:.3f})",
            f"{paired['faster']} / {paired['slower']}", f"{paired['p_value']:.2f}"]


def record_section(record: Path, figures: Path, rel: str) -> list[str]:
    """The report's lines on one kept run: budget, learning curve figure and table."""
    from mjexplore.eval.learning_curve import (
        baseline_means,
        best_evaluation,
        layout_name,
        learning_curve,
        paired_ratio,
        read_evaluations,
        run_revision,
    )
    from mjexplore.eval.plots import learning_curve_figure
    from mjexplore.eval.sweep import markdown_table

    name = record.name
    rows = read_evaluations(record)
    facts = json.loads((record / FACTS_FILE).read_text()) if (record / FACTS_FILE).is_file() \
        else {}
    points = learning_curve(rows)
    baselines = record_baselines(record, {layout_name(r["scene"]) for r in rows})
    means = baseline_means(baselines)
    best = best_evaluation(points)
    lines = [f"### {name}", ""]
    decisions = facts.get("decisions_trained")
    sessions = facts.get("sessions") or []
    started = sessions[0]["revision"] if sessions else run_revision(record)
    lines += [f"Started at revision `{(started or 'unknown')[:7]}`"
              + (f"; {decisions:,} decisions trained so far. " if decisions else ". ")
              + _sessions_line(facts), ""]
    figure = figures / f"training_{name}.png"
    learning_curve_figure(points, {n: m["mean_exploration_time_s"] for n, m in means.items()},
                          best, figure, title=name)
    lines += [f"![{name}: validation exploration time against decisions trained]"
              f"({rel}/{figure.name})", ""]
    # Paired in full against the first baseline there is (the prior when the run has one);
    # against plain nearest-frontier as a ratio beside it.
    main = next((n for n in ("pocket_nearest", "nearest") if n in baselines), None)
    beside = "nearest" if main == "pocket_nearest" and "nearest" in baselines else None
    table = []
    for p in points:
        mine = [r for r in rows if r["steps"] == p["steps"]]
        row = [f"{p['steps']:,}" + (" (kept)" if p is best else ""),
               f"{p['explored']}/{p['layouts']}", f"{p['mean_exploration_time_s']:.1f}",
               *_ratio_cells(paired_ratio(mine, baselines[main]) if main else None)]
        if beside:
            row.append(_ratio_cells(paired_ratio(mine, baselines[beside]))[0])
        table.append(row)
    header = ["decisions", "explored", "mean ET (s)", f"/ {main or 'baseline'} (95 % CI)",
              "faster / slower", "sign p"] + ([f"/ {beside} (95 % CI)"] if beside else [])
    lines += [markdown_table(header, table), ""]
    if means:
        said = "; ".join(f"{n} {m['mean_exploration_time_s']:.1f} s ({m['explored']}/"
                         f"{m['layouts']} explored)" for n, m in means.items())
        kept = [r for r in rows if best is not None and r["steps"] == best["steps"]]
        oracle = paired_ratio(kept, baselines["oracle"]) if "oracle" in baselines else None
        lines += [f"On the same layouts: {said}." + (
            f" The kept evaluation against the oracle, paired: {oracle['ratio']:.3f} "
            f"({oracle['ci95'][0]:.3f}-{oracle['ci95'][1]:.3f})." if oracle else ""), ""]
    departures = facts.get("departures")
    if departures and departures.get("share") is not None:
        trained = departures.get("trained")
        lines += [("The policy " + (f"trained {trained:,} decisions" if trained else "kept"))
                  + f" departs from its prior in {departures['departures']} of "
                  f"{departures['decisions']} decisions ({100 * departures['share']:.1f} %) "
                  "on the validation layouts.", ""]
    return lines


def training_section(data_dir: Path, figures: Path, rel: str) -> list[str]:
    """The report's section on the training runs kept in ``DATA/training/`` ([] if none)."""
    records = sorted(p for p in (data_dir / TRAINING_DIR).glob("*") if
                     (p / "eval.csv").is_file()) if (data_dir / TRAINING_DIR).is_dir() else []
    if not records:
        return []
    lines = ["## Training runs", "",
             "Kept by `mjexplore collect-training RUN`. Each curve is the mean exploration "
             "time (simulated s) on the run's validation layouts at each evaluation, against "
             "the decisions trained; the lines are pocket_nearest (the policy's prior alone, "
             "for policies that have one), plain nearest-frontier and the ground-truth oracle "
             "on the same layouts with the same settings. Ratios are paired per layout: the "
             "mean of per-layout ratios with its bootstrap 95 % interval, layouts faster and "
             "slower, and the sign test. Model selection keeps the evaluation marked (every "
             "layout explored first, then the fastest); final figures belong on test layouts "
             "no choice looked at, not on these.", ""]
    for record in records:
        lines += record_section(record, figures, rel)
    return lines
