"""The velocity check against people (navigation/safety.py) and people who do not walk into
robots (sim/people.py)."""

from __future__ import annotations

import numpy as np
import pytest

from mjexplore.navigation.safety import safe_command
from mjexplore.scenes.canonical import resolve_scene
from mjexplore.sim.motion import BODY_CENTRE_X, BODY_RADIUS
from mjexplore.sim.people import ROBOT_GAP, Crowd, PeopleConfig

STILL = np.zeros((1, 2))


def test_a_robot_driving_at_a_person_slows_then_stops():
    pose = np.array([0.0, 0.0, 0.0])
    far = np.array([[3.0, 0.0]])
    assert safe_command(pose, 0.5, 0.0, far, STILL, 0.25) == (0.5, 0.0)
    # 0.7 m ahead: the full speed would close the gap within the second, half speed not.
    near = np.array([[0.7 + BODY_CENTRE_X + BODY_RADIUS, 0.0]])
    v, w = safe_command(pose, 0.5, 0.0, near, STILL, 0.25)
    assert 0.0 < v < 0.5 and w == 0.0
    touching = np.array([[0.05 + BODY_RADIUS + 0.25 + BODY_CENTRE_X, 0.0]])
    assert safe_command(pose, 0.5, 0.3, touching, STILL, 0.25) in ((0.0, 0.3), (0.0, 0.0))


def test_driving_away_from_a_person_or_past_one_is_kept():
    pose = np.array([0.0, 0.0, 0.0])
    behind = np.array([[-0.6, 0.0]])
    assert safe_command(pose, 0.5, 0.0, behind, STILL, 0.25) == (0.5, 0.0)
    aside = np.array([[1.0, 1.2]])
    assert safe_command(pose, 0.5, 0.0, aside, STILL, 0.25) == (0.5, 0.0)


def test_a_person_walking_at_a_standing_robot_holds_it_still():
    pose = np.array([0.0, 0.0, 0.0])
    coming = np.array([[1.2, 0.0]])
    assert safe_command(pose, 0.5, 0.5, coming, np.array([[-1.2, 0.0]]), 0.25) == (0.0, 0.0)


@pytest.fixture(scope="module")
def office():
    return resolve_scene("office").ground_truth


def test_people_do_not_walk_into_a_robot(office):
    """A person heading straight at a standing robot, with no social force from robots to
    steer it off, is held ROBOT_GAP from the robot's body; without the check it walks in."""
    cfg = PeopleConfig(count=10, fluctuation=0.0, robot=(0.0, 0.3))
    crowd = Crowd(cfg, office, np.random.default_rng(3))
    for _ in range(20):  # Under way.
        crowd.step(0.1)
    walking = int(np.argmax(np.linalg.norm(crowd.velocities, axis=1)))
    heading = crowd.velocities[walking] / np.linalg.norm(crowd.velocities[walking])
    robot = crowd.positions[walking] + 0.8 * heading
    least = np.inf
    for _ in range(30):
        crowd.step(0.1, robot[None], BODY_RADIUS)
        least = min(least, float(np.linalg.norm(crowd.positions[walking] - robot)))
    assert least >= cfg.radius + BODY_RADIUS + ROBOT_GAP - 1e-9
