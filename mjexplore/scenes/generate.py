"""Generated scenes: a family, a size and a seed in, a validated :class:`Scene` out."""

from __future__ import annotations

import dataclasses

import numpy as np

from mjexplore.errors import UserInputError
from mjexplore.scenes.generators import GeneratorConfig, generate_solid, parse_family
from mjexplore.scenes.scene import Scene, fill_unreachable, ground_truth_from_solid, pick_start

GENERATOR_VERSION = 1
MIN_SIDE_M = 4.0
MAX_SIDE_M = 200.0


def generate_scene(family: str, width: float, height: float, seed: int,
                   resolution: float = 0.05, config: GeneratorConfig | None = None,
                   name: str | None = None) -> Scene:
    """Generates a scene whose free space is one region the robot's footprint reaches.

    Args:
        family: 'office', 'maze', 'loop', 'corridor', 'rooms', 'hall', 'labmaze', or several
            joined by '+' (e.g. 'loop+rooms').
        width: Size along x in metres, outer walls included.
        height: Size along y in metres.
        seed: Seed of the only random generator used; equal seeds give equal scenes.
        resolution: Ground-truth cell side in metres.
        config: Generator dimensions (wall thickness, door widths, ...).
        name: Scene name; defaults to ``{family}_{width}x{height}_s{seed}``.

    Raises:
        UserInputError: unknown family, or a size out of range for it.
    """
    parse_family(family)
    for label, side in (("width", width), ("height", height)):
        if not MIN_SIDE_M <= side <= MAX_SIDE_M:
            raise UserInputError(f"scene {label} {side} m is out of range: give {MIN_SIDE_M:g} to "
                                 f"{MAX_SIDE_M:g} m (e.g. --size 40x25).")
    if not 0.01 <= resolution <= 0.5:
        raise UserInputError(f"resolution {resolution} m is out of range: use 0.01 to 0.5 m.")
    if seed < 0:
        raise UserInputError(f"seed {seed} is negative: give a seed >= 0.")
    config = config or GeneratorConfig()
    rng = np.random.default_rng(seed)
    solid = generate_solid(family, width, height, resolution, rng, config)
    solid = fill_unreachable(solid, resolution)
    start = pick_start(~solid, resolution, rng)
    metadata = {
        "source": "generated",
        "family": family,
        "seed": int(seed),
        "size_m": [float(width), float(height)],
        "generator_version": GENERATOR_VERSION,
        "generator_config": dataclasses.asdict(config),
    }
    return Scene(
        name=name or f"{family.replace('+', '_')}_{width:g}x{height:g}_s{seed}",
        ground_truth=ground_truth_from_solid(solid, resolution),
        solid=solid,
        start=start,
        metadata=metadata,
    )
