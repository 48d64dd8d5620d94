"""Training curves of a run folder: the learning curve against the prior and the oracle,
the held-out evaluation per layout, and episode return and length (TensorBoard scalars), as
one PNG and one JSON line.

The learning curve is the mean validation exploration time (simulated s) of each evaluation
in ``RUN/eval.csv`` against the decisions trained, with horizontal lines measured on the
same validation layouts (the run's ``eval.scene_list()``) with the same episode settings and
seed: ``pocket_nearest`` (the policy's prior alone: the nearest node by path, counting each
``policy.prior_pocket_m`` metres farther per unit of pocket probability; ``prior`` mode of
``mjexplore probe-policy``; v2 and v3 observations only), ``nearest`` (the classic
nearest-frontier explorer; its mode there) and ``oracle`` (the ground-truth explorer). They
are measured once and cached in ``RUN/baselines.json`` (see
:mod:`mjexplore.eval.learning_curve`); ``--recompute-baselines`` measures them again,
``--no-baselines`` leaves them out.

The JSON line holds:

* ``rollout/...``: the last TensorBoard rollout figures; ``steps``: the last step logged;
  ``evaluations``: the eval.csv rows (as before);
* ``decisions_trained`` and ``checkpoint`` (``checkpoints/latest.json``), ``revision`` (the
  git revision the run was trained at), ``shipped`` (``best.safetensors``, else
  ``policy.safetensors``, and the decisions it was trained), ``imitation`` (the warm
  start's decisions, episodes and wall s, when ``imitation.json`` exists), ``sessions`` and
  ``sessions_wall_s`` (``sessions.json``, runs since 51c9f13: each start or resume's host,
  cores, device, steps, wall and learner CPU s, warm start included);
* ``wall_s``: what TensorBoard recorded of the time: ``collect`` and ``update`` (sums of
  ``time/collect_s`` and ``time/update_s``: rollouts and PPO updates, s) and ``span`` (first
  to last event of each TensorBoard folder, summed over resumes: evaluations and
  checkpoints included, but not the first rollout and update, nor a warm start);
* ``workers``: ``n_envs``, ``torch_threads`` and ``update_threads`` from the run's config
  (settings, not the machine);
* ``curve`` (per evaluation: steps, mean exploration time s, layouts explored, score),
  ``best`` (the evaluation model selection kept, ``best.safetensors``);
* ``baselines``: per baseline its mean exploration time (s) and layouts explored, with
  ``cached`` and ``measured_at`` (per baseline, the revision of the code that measured it);
* ``best_vs_pocket_nearest`` and ``best_vs_oracle``: the best evaluation's per-layout
  exploration times over the baseline's: mean of per-layout ratios, bootstrap 95 % interval,
  layouts faster and slower, sign test p-value;
* with ``--departures``: ``departures``, how often the shipped policy (``--weights``,
  default ``RUN/best.safetensors`` else ``RUN/policy.safetensors``; ``trained``: the
  decisions it was trained) departs from its prior on the validation layouts
  (:func:`mjexplore.eval.learning_curve.prior_departures`), also written to
  ``RUN/departures.json`` (``mjexplore collect-training`` keeps it).

Runs before 51c9f13 do not record the machine's cores, nor the wall time of a whole run
(warm start to end, across resumes): ``wall_s`` is what TensorBoard holds of it.

``mjexplore plot-training RUN OUT.png`` runs it (:func:`plot_training`).
"""

from __future__ import annotations

import io
import json
import multiprocessing as mp
from pathlib import Path

import matplotlib.pyplot as plt

from mjexplore.errors import UserInputError
from mjexplore.eval.learning_curve import (
    BASELINES,
    baseline_means,
    best_evaluation,
    cached_baselines,
    layout_name,
    learning_curve,
    paired_ratio,
    prior_departures,
    read_evaluations,
    run_facts,
    shipped_weights,
    start_revision,
)
from mjexplore.eval.plots import draw_learning_curve
from mjexplore.eval.probe import probe_episode
from mjexplore.eval.training_record import DEPARTURES_FILE
from mjexplore.io.atomic import (
    check_output_file,
    write_bytes_atomic,
    write_text_atomic,
)

# probe_episode's modes for the baselines.
PROBE_MODES = {"pocket_nearest": "prior", "nearest": "nearest", "oracle": "oracle"}


def _accumulators(run: Path) -> list:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = []
    for folder in sorted((run / "tb").glob("*")):
        acc = EventAccumulator(str(folder))
        acc.Reload()
        out.append(acc)
    return out


def scalars(run: Path) -> dict[str, list[tuple[int, float]]]:
    """Every TensorBoard scalar of the run: tag -> (step, value), sorted by step."""
    out: dict[str, list[tuple[int, float]]] = {}
    for acc in _accumulators(run):
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in acc.Scalars(tag))
    return {k: sorted(v) for k, v in out.items()}


def wall_times(run: Path) -> dict[str, float]:
    """What TensorBoard recorded of the run's time, s (see the module docstring: ``collect``,
    ``update``, ``span``); {} without TensorBoard folders."""
    totals = {"collect": 0.0, "update": 0.0, "span": 0.0}
    found = False
    for acc in _accumulators(run):
        tags = acc.Tags()["scalars"]
        stamps = [e.wall_time for tag in tags for e in acc.Scalars(tag)]
        if not stamps:
            continue
        found = True
        totals["span"] += max(stamps) - min(stamps)
        for name in ("collect", "update"):
            if f"time/{name}_s" in tags:
                totals[name] += sum(e.value for e in acc.Scalars(f"time/{name}_s"))
    return {k: round(v, 1) for k, v in totals.items()} if found else {}


def _probe_job(job: tuple[str, str, int, str]) -> dict:
    config_path, mode, seed, scene = job
    return probe_episode((config_path, "", mode, seed, scene))


def applicable_baselines(config) -> list[str]:
    """The baselines that apply to a run: ``pocket_nearest`` only with v2 or v3 GVN
    observations (the path feature its rule reads)."""
    from mjexplore.envs.observation import POSED

    return [n for n in BASELINES if n != "pocket_nearest" or (
        config.kind == "gvn" and config.env.observation.features in POSED)]


def measure_baselines(config_path: Path, workers: int):
    """A measuring function for :func:`~mjexplore.eval.learning_curve.cached_baselines`:
    ``mjexplore probe-policy``'s ``prior``, ``nearest`` and ``oracle`` episodes on the
    config's validation layouts."""
    def measure(config, names: list[str]) -> dict[str, list[dict]]:
        jobs = [(str(config_path), PROBE_MODES[n], config.eval.seed, scene)
                for n in names for scene in config.eval.scene_list()]
        if workers > 1:
            with mp.get_context("spawn").Pool(workers) as pool:
                rows = pool.map(_probe_job, jobs, chunksize=1)
        else:
            rows = [_probe_job(job) for job in jobs]
        by_mode = {v: k for k, v in PROBE_MODES.items()}
        out: dict[str, list[dict]] = {n: [] for n in names}
        for row in rows:
            out[by_mode[row["mode"]]].append({
                "layout": layout_name(row["scene"]),
                "exploration_time_s": row["exploration_time_s"],
                "path_length_m": row["path_length_m"], "explored": row["explored"]})
        return out
    return measure


def departures(weights: Path, config) -> dict:
    """:func:`~mjexplore.eval.learning_curve.prior_departures` of the weights on the run's
    validation layouts (this process, one torch thread)."""
    import torch

    from mjexplore.policies.weights import load_policy

    torch.set_num_threads(1)
    policy, meta = load_policy(weights, expected_kind=config.kind)
    return {"weights": str(weights), "trained": meta["provenance"].get("num_timesteps"),
            **prior_departures(policy, config)}


def report(run: Path, baselines: bool = True, recompute: bool = False, workers: int = 1,
           departures_of: Path | None = None) -> tuple[dict, dict]:
    """The JSON figures of a run folder (see the module docstring) and what the plot needs
    beyond them (``rows``: eval.csv; ``scalars``; ``lines``: baseline means, s)."""
    s = scalars(run)
    rows = read_evaluations(run)
    figures: dict = {tag: round(v[-1][1], 3) for tag, v in s.items()
                     if tag.startswith("rollout/")}
    figures["steps"] = max((v[-1][0] for v in s.values()), default=0)
    figures["evaluations"] = [{k: r[k] for k in ("steps", "scene", "exploration_time_s",
                                                 "path_length_m", "end_reason")} for r in rows]
    figures.update(run_facts(run))
    wall = wall_times(run)
    if wall:
        figures["wall_s"] = wall
    config = None
    if (run / "config.yaml").is_file():
        from mjexplore.learning.train_config import load_train_config

        config = load_train_config(run / "config.yaml")
        figures["workers"] = {"n_envs": config.n_envs, "torch_threads": config.torch_threads,
                              "update_threads": config.update_threads or config.torch_threads}
    points = learning_curve(rows)
    figures["curve"] = points
    best = best_evaluation(points)
    if best is not None:
        figures["best"] = best
    lines: dict[str, float] = {}
    if baselines and config is not None:
        entry, cached = cached_baselines(run, config, start_revision(run),
                                         measure_baselines(run / "config.yaml", workers),
                                         recompute, applicable_baselines(config))
        means = baseline_means(entry)
        figures["baselines"] = {**means, "cached": cached, "measured_at": entry["measured_at"],
                                "pocket_m": config.policy.prior_pocket_m}
        lines = {name: m["mean_exploration_time_s"] for name, m in means.items()}
        if best is not None:
            mine = [r for r in rows if r["steps"] == best["steps"]]
            for name in means:
                paired = paired_ratio(mine, entry[name])
                if paired is not None:
                    figures[f"best_vs_{name}"] = paired
    if departures_of is not None and config is not None:
        figures["departures"] = departures(departures_of, config)
        # Kept beside the run for mjexplore collect-training.
        write_text_atomic(run / DEPARTURES_FILE, json.dumps(figures["departures"]) + "\n")
    return figures, {"rows": rows, "scalars": s, "lines": lines, "best": best}


def plot(figures: dict, extra: dict, out: Path) -> None:
    """The four panels: learning curve with the baselines' lines, per-layout curves, episode
    return and length; written atomically as PNG."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 7.2))
    draw_learning_curve(axes[0, 0], figures["curve"], extra["best"], extra["lines"])
    ax = axes[0, 1]
    rows = extra["rows"]
    scenes = sorted({r["scene"] for r in rows})
    for scene in scenes:
        mine = [r for r in rows if r["scene"] == scene]
        ax.plot([r["steps"] for r in mine], [r["exploration_time_s"] for r in mine], "o-",
                label=layout_name(scene), linewidth=0.8, markersize=3)
    if 0 < len(scenes) <= 8:
        ax.legend(fontsize=7)
    ax.set_xlabel("decisions trained")
    ax.set_title("per validation layout (s, simulated)")
    s = extra["scalars"]
    for ax, tag, label in ((axes[1, 0], "rollout/ep_rew_mean", "episode return"),
                           (axes[1, 1], "rollout/ep_len_mean", "decisions per episode")):
        if tag in s:
            steps, values = zip(*s[tag], strict=True)
            ax.plot(steps, values, marker="." if len(steps) < 50 else None)
        ax.set_xlabel("decisions trained")
        ax.set_title(label)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(out, buf.getvalue())


def plot_training(run: Path, out: Path, workers: int = 2, baselines: bool = True,
                  recompute: bool = False, departures_of_shipped: bool = False,
                  weights: Path | None = None) -> dict:
    """Writes the run's training curves to the PNG ``out`` and returns its figures (see the
    module docstring); ``departures_of_shipped`` also counts the departures of ``weights``
    (default: the run's shipped weights) from their prior.

    Raises:
        UserInputError: ``run`` is not a folder; --departures without weights, config or
            prior.
    """
    if not run.is_dir():
        raise UserInputError(f"{str(run)!r} is not a folder: give a run folder of "
                             "'mjexplore train --out'.")
    check_output_file(out, "OUT", (".png",))
    chosen = None
    if departures_of_shipped:
        chosen = weights or shipped_weights(run)
        if chosen is None:
            raise UserInputError(f"--departures: {str(run)!r} holds no best.safetensors or "
                                 "policy.safetensors; pass --weights.")
        if not (run / "config.yaml").is_file():
            raise UserInputError(f"--departures needs {str(run / 'config.yaml')!r}.")
        from mjexplore.learning.train_config import load_train_config

        if load_train_config(run / "config.yaml").policy.prior_temperature is None:
            raise UserInputError("--departures: the run's policy has no prior "
                                 "(policy.prior_temperature is null): there is nothing to "
                                 "depart from.")
    figures, extra = report(run, baselines=baselines, recompute=recompute, workers=workers,
                            departures_of=chosen)
    plot(figures, extra, out)
    return figures
