"""What the replay benchmarks (``bench_topology.py``, ``bench_scan_matching.py``,
``bench_localizer.py``) share: a recorded run of the reactive wanderer to replay, and the
summary of the replay's timings."""

from __future__ import annotations

import numpy as np

from mjexplore.navigation.wander import WanderController
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.simulator import SimConfig, Simulator


def record_wander(scene: str, seconds: float, seed: int, config: SimConfig | None = None):
    """The simulator after ``seconds`` (simulated) of the seeded wanderer in ``scene``, and
    every scan of the run."""
    sim = Simulator(resolve_scene(scene), config)
    controller = WanderController(rng=np.random.default_rng(seed))
    scans = [sim.latest_scan]
    while sim.time < seconds - 1e-9:
        sim.command(*controller(sim.latest_scan, sim.pose))
        scans += sim.step(0.1)
    return sim, scans


def median_p99_ms(values_s: list[float]) -> tuple[float, float]:
    """Median and 99th percentile of timings given in seconds, in milliseconds."""
    ms = np.asarray(values_s) * 1e3
    return round(float(np.median(ms)), 3), round(float(np.percentile(ms, 99)), 3)
