"""Training throughput of training/gvn_v2.yaml's learner against SB3's defaults, same run.

One round of PPO (a rollout of n_steps decisions on each of n_envs worker envs, then the
update) as ``mjexplore train`` runs it, twice, each in a fresh process with the same seed
(so both collect the same decisions):

* ``defaults``: minibatches of single decisions drawn at random (SB3's), the update on
  ``torch_threads``, every TER of every observation encoded at each forward, and malloc
  as the CLI sets it for long episodes (a 128 KiB mmap threshold): the learner before
  issue 17's speed-ups.
* ``recipe``: the config's ``ppo.minibatch_block`` and ``update_threads``, inference that
  encodes each TER once per weights (``EncodedTers``), and malloc reusing freed memory
  (``mjexplore.episode.workers.reuse_freed_memory``), as ``mjexplore train`` runs now.

Prints one JSON line: decisions per second of each and ``speedup`` (recipe / defaults),
with the rollout and update milliseconds per decision.

Usage: python tools/bench_learner.py [--config training/gvn_v2.yaml] [--n-steps 128]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys


def run(config_path: str, variant: str, n_steps: int) -> dict[str, float]:
    from mjexplore.episode.workers import bound_heap_growth, reuse_freed_memory
    from mjexplore.learning.train_config import load_train_config
    from mjexplore.learning.training import ppo_round

    config = load_train_config(config_path)
    config = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, n_steps=n_steps))
    setup = None
    if variant == "defaults":
        bound_heap_growth()
        config = dataclasses.replace(config, update_threads=None, ppo=dataclasses.replace(
            config.ppo, minibatch_block=1))

        def setup(model) -> None:
            for extractor in (model.policy.pi_features_extractor,
                              model.policy.vf_features_extractor):
                extractor.gvn.encoded.capacity = 0  # Nothing kept between calls.
    else:
        reuse_freed_memory()
    return ppo_round(config, model_setup=setup)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="training/gvn_v2.yaml")
    parser.add_argument("--n-steps", type=int, default=128,
                        help="decisions per env in the rollout (a multiple of the block)")
    parser.add_argument("--variant", choices=("defaults", "recipe"),
                        help="run this one only (in this process) and print its timings")
    args = parser.parse_args()
    if args.variant:
        print(json.dumps(run(args.config, args.variant, args.n_steps)))
        return
    out: dict[str, float | str] = {"config": args.config}
    rates = {}
    for variant in ("defaults", "recipe"):  # Each in a process of its own (malloc settings).
        done = subprocess.run([sys.executable, __file__, "--config", args.config, "--n-steps",
                               str(args.n_steps), "--variant", variant],
                              capture_output=True, text=True, check=True)
        r = json.loads(done.stdout.splitlines()[-1])
        n = r["decisions"]
        rates[variant] = n / (r["rollout_s"] + r["update_s"])
        out[f"{variant}_decisions_per_s"] = round(rates[variant], 2)
        out[f"{variant}_rollout_ms_per_decision"] = round(r["rollout_s"] / n * 1e3, 1)
        out[f"{variant}_update_ms_per_decision"] = round(r["update_s"] / n * 1e3, 1)
    out["speedup"] = round(rates["recipe"] / rates["defaults"], 2)
    out["decisions"] = n
    print(json.dumps(out))


if __name__ == "__main__":
    main()
