"""Pedestrians walking in a building: the social force model, guided around the walls.

Each person is a disc (``radius``, about a body's shoulder width) that walks from one random
goal on the free space of the ground truth to the next at a preferred speed of its own
(uniform in ``speed``, 0.6-1.4 m/s). Its motion is Helbing and Molnar's social force model
("Social force model for pedestrian dynamics", Phys. Rev. E 51, 1995), in the circular
specification of Helbing, Farkas and Vicsek ("Simulating dynamical features of escape
panic", Nature 407, 2000) without its contact (body and friction) forces, per unit mass:

* driving: ``(v0 e - v) / tau``, towards the desired direction ``e`` at the preferred speed
  ``v0``, relaxing in ``tau`` (0.5 s);
* from another person ``j``: ``A exp((r_i + r_j - d_ij) / B) n_ij`` (``n_ij`` the unit vector
  from ``j`` to ``i``), weighted by the field of view, ``lambda + (1 - lambda) (1 + cos phi)
  / 2`` (Helbing and Johansson 2009; ``phi`` the angle between ``i``'s heading and ``j``);
* from the nearest wall: the same form with the distance to the wall;
* from a robot: the same form with the robot's bounding circle, so people step around it;
* from those ahead, a push to the right of one's way (``keep_right``), so that two people
  walking at each other pass, and a small random force (the model's fluctuations).

The desired direction follows the shortest path to the goal around the walls: a geodesic
distance field from the goal (Dijkstra on a 0.2 m grid of the cells a person fits in), whose
steepest descent the person follows; a field, and the way down it from every cell, are made
once per goal. A person within ``goal_tolerance`` of its goal draws the next one, and so does
a person held up (no headway) for ``give_way_s`` (a crowd in a corridor can hold itself up,
as crowds do). Velocities are capped at 1.3 times the preferred speed, and the state
advances by semi-implicit Euler steps of ``dt``; a step into a wall slides along it, a step
into a robot's body past it (people do not walk into robots). The crowd lives on the ground
truth; the physics and kinematic worlds carry it as bodies the lidar sees and the robot can
touch (:class:`~mjexplore.sim.simulator.Simulator`), the grid world as discs its lidar casts
(:class:`~mjexplore.sim.grid_world.GridWorld`).

Everything random comes from the generator given (start places, goals, speeds), so a seed
replays the same crowd. People start on cells they fit in, apart from each other and at
least ``keep_clear`` metres from given points (the robots' starts); a crowd the free space
cannot hold is refused with the number that fits.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from mjexplore.errors import UserInputError
from mjexplore.maps import GridMap

GUIDE_CELL_M = 0.2  # Cell side of the guidance grid, metres.
GUIDE_MARGIN_M = 0.1  # Clearance beyond a person's radius of the cells routes pass, metres.
# Free space a person needs to walk in a crowd: a square of this side per person, metres
# (a dense but walkable crowd: about 1 person per 1.2 m^2).
SPACE_PER_PERSON_M = 1.1


# Least gap a person's step leaves to a robot's body, metres.
ROBOT_GAP = 0.03

@dataclasses.dataclass(frozen=True, kw_only=True)
class PeopleConfig:
    """Pedestrian settings (metres, seconds, metres per second).

    Attributes:
        count: How many people walk in the building.
        radius: A person's disc (shoulders), metres.
        height: A person's height (what a lidar at any mounting height sees), metres.
        speed: (least, greatest) preferred walking speed, drawn uniformly per person.
        relaxation_s: ``tau``, how fast a person returns to its preferred velocity.
        social: (A in m/s^2, B in m) of the repulsion between people.
        wall: (A, B) of the repulsion from walls.
        robot: (A, B) of the repulsion from robots.
        field_of_view: ``lambda``: the weight of a force from behind (1: isotropic).
        keep_right: The push to the right of one's way from people and robots ahead, as a
            share of their repulsion.
        fluctuation: Standard deviation of the random force each step (m/s^2), the
            model's fluctuations: they break the standstills of a symmetric crowd.
        goal_tolerance: A goal this close counts as reached.
        give_way_s: A person held up this long (making less than 0.1 m/s of headway
            towards its goal) gives the goal up for another, as people held up in a crowd
            turn elsewhere.
        min_goal_distance: Least straight distance from a person to its next goal.
        keep_clear: Least distance of a person's start from the points given (the robots'
            starts).
        dt: Integration step, seconds.
        density: People per 100 m^2 of the floor a person can walk (its guidance cells);
            when > 0 it sets the count for each scene (:func:`for_scene`), rounded, in place
            of ``count``.
    """

    count: int = 0
    radius: float = 0.25
    height: float = 1.7
    speed: tuple[float, float] = (0.6, 1.4)
    relaxation_s: float = 0.5
    social: tuple[float, float] = (4.0, 0.3)
    wall: tuple[float, float] = (6.0, 0.15)
    robot: tuple[float, float] = (6.0, 0.3)
    field_of_view: float = 0.5
    keep_right: float = 0.5
    fluctuation: float = 0.2
    goal_tolerance: float = 0.5
    give_way_s: float = 5.0
    min_goal_distance: float = 3.0
    keep_clear: float = 1.0
    dt: float = 0.05
    density: float = 0.0

    def __post_init__(self) -> None:
        if self.count < 0:
            raise UserInputError(f"--people {self.count}: give 0 or more people.")
        if self.density < 0 or (self.density > 0 and self.count > 0):
            raise UserInputError(f"people density {self.density:g}: give 0 or more people per "
                                 "100 m^2, and a count or a density, not both.")
        if not (0 < self.radius and 0 < self.speed[0] <= self.speed[1] and self.dt > 0
                and self.relaxation_s > 0 and 0 <= self.field_of_view <= 1):
            raise ValueError("radius, speeds, dt and relaxation_s must be > 0 (speed[0] <= "
                             "speed[1]) and field_of_view in [0, 1]")


class Crowd:
    """The people of an episode (see the module docstring).

    Args:
        config: Pedestrian settings.
        ground_truth: The building's map (its free cells are where people walk).
        rng: The generator every random choice is drawn from.
        keep_clear: (k, 2) points people do not start near (the robots' starts).

    Attributes:
        positions: (n, 2) disc centres in the ``map`` frame, metres.
        velocities: (n, 2) metres per second.
        goals: (n, 2) current goals.
        preferred: (n,) preferred speeds.
        goals_reached: How many goals the people have reached in all.
        goals_abandoned: How many they gave up, blocked for ``give_way_s``.

    Raises:
        UserInputError: More people than the free space holds (the message says how many
            fit).
    """

    def __init__(self, config: PeopleConfig, ground_truth: GridMap, rng: np.random.Generator,
                 keep_clear: np.ndarray | None = None) -> None:
        self.config = config
        self.rng = rng
        self.time = 0.0
        self.goals_reached = 0
        self._map = ground_truth
        # Clearance from walls (and unknown) in metres on the map's cells.
        free = ground_truth.free.astype(np.uint8)
        self._clearance = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * \
            ground_truth.resolution
        self._guide = _GuideGrid(ground_truth, self._clearance, config.radius)
        n = config.count
        check_capacity(n, self._guide.capacity(config.radius))
        self.positions = self._spawn(n, np.zeros((0, 2)) if keep_clear is None
                                     else np.asarray(keep_clear, float).reshape(-1, 2))
        self.velocities = np.zeros((n, 2))
        self.preferred = rng.uniform(*config.speed, size=n)
        self.goals = np.zeros((n, 2))
        self.goals_abandoned = 0
        self._stood = np.zeros(n)  # Seconds each has stood blocked.
        # Per person and guidance cell, the point its way leads to next: the centre of the
        # neighbouring cell nearest its goal (NaN: none is nearer, head for the goal).
        self._aims = np.full((n, *self._guide.shape, 2), np.nan)
        self._guided = np.zeros(n, bool)  # Whether it has a way (else it stands).
        for i in range(n):
            self._new_goal(i)

    def __len__(self) -> int:
        return len(self.positions)

    # ------------------------------------------------------------------ set-up

    def _spawn(self, n: int, keep_clear: np.ndarray) -> np.ndarray:
        """``n`` start places on walkable cells, a body apart, ``keep_clear`` from the
        points given; drawn in turn from the walkable cells left."""
        cfg = self.config
        cells = self._guide.walkable_points()
        if len(keep_clear):
            near = np.linalg.norm(cells[:, None] - keep_clear[None], axis=2).min(axis=1)
            cells = cells[near >= cfg.keep_clear]
        out = np.zeros((n, 2))
        for i in range(n):
            if len(cells) == 0:
                raise UserInputError(f"{n} people do not fit apart in this building's free "
                                     f"space (only {i} did): give --people {i} or fewer.")
            out[i] = cells[int(self.rng.integers(len(cells)))]
            cells = cells[np.linalg.norm(cells - out[i], axis=1) >= 2.2 * cfg.radius]
        return out

    def _new_goal(self, i: int) -> None:
        """Draws person ``i``'s next goal: a walkable place it can reach, at least
        ``min_goal_distance`` away where there is one."""
        guide = self._guide
        cells = guide.reachable_points(self.positions[i])
        far = cells[np.linalg.norm(cells - self.positions[i], axis=1) >= self.config.
                    min_goal_distance]
        pool = far if len(far) else cells
        if len(pool) == 0:  # Walled in alone: it stands.
            self.goals[i] = self.positions[i]
            self._guided[i] = False
            return
        self.send(i, pool[int(self.rng.integers(len(pool)))])

    def send(self, i: int, goal: np.ndarray) -> None:
        """Sends person ``i`` to ``goal`` (a walkable point, ``map`` frame, metres) along
        the guidance grid's geodesic."""
        self.goals[i] = goal
        self._aims[i] = self._guide.next_points(self._guide.distance_field(self.goals[i]))
        self._guided[i] = True

    # ------------------------------------------------------------------ dynamics

    def step(self, duration: float, robots: np.ndarray | None = None,
             robot_radius: float = 0.194) -> None:
        """Advances the crowd by ``duration`` seconds (whole ``dt`` steps) with robots'
        bodies at ``robots`` ((k, 2) centres of discs of ``robot_radius``), held still
        during the step."""
        steps = max(0, int(round(duration / self.config.dt)))
        bodies = np.zeros((0, 2)) if robots is None else np.asarray(robots, float).reshape(-1, 2)
        for _ in range(steps):
            self._step(bodies, robot_radius)

    def _step(self, robots: np.ndarray, robot_radius: float) -> None:
        cfg = self.config
        n = len(self.positions)
        if n == 0:
            self.time += cfg.dt
            return
        p, v = self.positions, self.velocities
        heading = self._desired_directions()
        force = (self.preferred[:, None] * heading - v) / cfg.relaxation_s
        force += self._repulsion(p, p, 2 * cfg.radius, cfg.social, v, heading,
                                 exclude_self=True)
        if len(robots):
            force += self._repulsion(p, robots, cfg.radius + robot_radius, cfg.robot, v,
                                     heading)
        force += self._walls(p)
        force += self.rng.normal(0.0, cfg.fluctuation, size=(n, 2))
        v = v + cfg.dt * force
        speed = np.linalg.norm(v, axis=1)
        cap = 1.3 * self.preferred
        v *= np.minimum(1.0, cap / np.maximum(speed, 1e-9))[:, None]
        moved = p + cfg.dt * v
        # A step into a wall slides along it (the velocity into the wall taken away), or
        # is refused: the wall force keeps people off; this keeps the state valid whatever
        # the forces did.
        inside = self._clearance_at(moved) < 0.5 * cfg.radius
        if inside.any():
            normal = self._away_from_walls(p[inside])
            into = np.minimum((v[inside] * normal).sum(axis=1), 0.0)
            v[inside] -= into[:, None] * normal
            moved[inside] = p[inside] + cfg.dt * v[inside]
            still = self._clearance_at(moved) < 0.5 * cfg.radius
            moved[still] = p[still]
            v[still] = 0.0
        if len(robots):
            moved, v = self._clear_of_robots(p, moved, v, robots,
                                             cfg.radius + robot_radius + ROBOT_GAP)
        self.positions, self.velocities = moved, v
        self.time += cfg.dt
        reached = np.linalg.norm(self.goals - moved, axis=1) <= cfg.goal_tolerance
        slow = (v * heading).sum(axis=1) < 0.1  # No headway towards the goal.
        self._stood = np.where(slow & ~reached, self._stood + cfg.dt, 0.0)
        for i in np.flatnonzero(reached):
            self.goals_reached += 1
            self._new_goal(int(i))
        for i in np.flatnonzero(self._stood >= cfg.give_way_s):  # Blocked: go elsewhere.
            self.goals_abandoned += 1
            self._stood[i] = 0.0
            self._new_goal(int(i))

    def _clear_of_robots(self, p: np.ndarray, moved: np.ndarray, v: np.ndarray,
                         robots: np.ndarray, contact: float) -> tuple[np.ndarray, np.ndarray]:
        """The step with the motion to within ``contact`` of a robot's body centre taken
        away: a person does not walk into a robot (its step slides past the body, or is
        refused), as into a wall."""
        for centre in robots:
            away = p - centre
            dist = np.linalg.norm(away, axis=1)
            into = np.linalg.norm(moved - centre, axis=1) < np.minimum(contact, dist)
            if not into.any():
                continue
            normal = away[into] / np.maximum(dist[into], 1e-9)[:, None]
            toward = np.minimum((v[into] * normal).sum(axis=1), 0.0)
            v[into] -= toward[:, None] * normal
            moved[into] = p[into] + self.config.dt * v[into]
            still = np.linalg.norm(moved - centre, axis=1) < np.minimum(contact, dist)
            moved[still], v[still] = p[still], 0.0
        return moved, v

    def _desired_directions(self) -> np.ndarray:
        """(n, 2) unit vectors down each person's distance field (straight at the goal when
        it is in sight on the guidance grid's neighbourhood)."""
        rows, cols = self._guide.cells_of(self.positions)
        aim = self._aims[np.arange(len(self.positions)), rows, cols]
        aim = np.where(np.isnan(aim), self.goals, aim)
        d = aim - self.positions
        norm = np.hypot(d[:, 0], d[:, 1])
        out = np.where((norm > 1e-9)[:, None], d / np.maximum(norm, 1e-9)[:, None], 0.0)
        out[~self._guided] = 0.0
        return out

    def _repulsion(self, p: np.ndarray, others: np.ndarray, contact: float,
                   strength: tuple[float, float], v: np.ndarray, heading: np.ndarray,
                   exclude_self: bool = False) -> np.ndarray:
        """(n, 2) the exponential repulsion of ``others`` on the people at ``p``, weighted
        by the field of view of each person's velocity, and from those ahead a push of
        ``keep_right`` times it to the right of the person's desired direction
        (``heading``; to the left with a wall on the right): two people walking at each
        other pass, each on its right, as pedestrians do, where the symmetric force alone
        would stop them face to face."""
        a, b = strength
        diff = p[:, None, :] - others[None, :, :]
        d = np.linalg.norm(diff, axis=2)
        if exclude_self:
            np.fill_diagonal(d, np.inf)
        n_ij = diff / np.maximum(d, 1e-9)[..., None]
        magnitude = a * np.exp((contact - d) / b)
        speed = np.linalg.norm(v, axis=1, keepdims=True)
        e = np.where(speed > 1e-6, v / np.maximum(speed, 1e-9), 0.0)
        cos_phi = -(n_ij * e[:, None, :]).sum(axis=2)  # Other ahead: +1.
        lam = self.config.field_of_view
        weight = np.where(speed > 1e-6, lam + (1 - lam) * (1 + cos_phi) / 2, 1.0)
        push = magnitude * weight
        ahead = (push * np.clip(cos_phi, 0.0, None)).sum(axis=1)
        right = np.column_stack([heading[:, 1], -heading[:, 0]])
        # Along a wall on one's right, one gives way on the left.
        room = 2 * self.config.radius
        sides = self._clearance_at(np.concatenate([p + room * right, p - room * right]))
        walled = (sides[:len(p)] < room) & (sides[len(p):] >= room)
        side = np.where(walled[:, None], -right, right)
        return (push[..., None] * n_ij).sum(axis=1) + \
            self.config.keep_right * ahead[:, None] * side

    def _clearance_at(self, xy: np.ndarray) -> np.ndarray:
        """Wall clearance (metres) at the points (n, 2), those off the map at its edge."""
        grid = self._map
        cols = np.floor((xy[:, 0] - grid.origin[0]) / grid.resolution).astype(np.int64)
        rows = np.floor((xy[:, 1] - grid.origin[1]) / grid.resolution).astype(np.int64)
        return self._clearance[np.minimum(np.maximum(rows, 0), grid.shape[0] - 1),
                               np.minimum(np.maximum(cols, 0), grid.shape[1] - 1)]

    def _away_from_walls(self, p: np.ndarray, at: np.ndarray | None = None) -> np.ndarray:
        """(n, 2) unit vectors away from the nearest wall (the clearance's gradient);
        ``at``: the clearance at p +- h along x, then y (4n,), if looked up already."""
        h = self._map.resolution
        n = len(p)
        if at is None:
            at = self._clearance_at(np.concatenate([p + (h, 0), p - (h, 0), p + (0, h),
                                                    p - (0, h)]))
        g = np.column_stack([at[:n] - at[n:2 * n], at[2 * n:3 * n] - at[3 * n:]])
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        return np.where(norm > 1e-9, g / np.maximum(norm, 1e-9), 0.0)

    def _walls(self, p: np.ndarray) -> np.ndarray:
        """(n, 2) the nearest wall's repulsion."""
        a, b = self.config.wall
        h = self._map.resolution
        at = self._clearance_at(np.concatenate([p, p + (h, 0), p - (h, 0), p + (0, h),
                                                p - (0, h)]))
        d = at[:len(p)]
        return (a * np.exp((self.config.radius - d) / b))[:, None] * \
            self._away_from_walls(p, at[len(p):])

    # ------------------------------------------------------------------ readings

    def distances_to(self, points: np.ndarray) -> np.ndarray:
        """(k,) each point's distance to the nearest person's disc (inf without people)."""
        points = np.asarray(points, float).reshape(-1, 2)
        if len(self.positions) == 0:
            return np.full(len(points), math.inf)
        d = np.linalg.norm(points[:, None] - self.positions[None], axis=2).min(axis=1)
        return d - self.config.radius


def check_capacity(count: int, fits: int) -> None:
    """Refuses ``count`` people where the free space holds ``fits``.

    Raises:
        UserInputError: too many (the message says how many fit).
    """
    if count > fits:
        raise UserInputError(f"{count} people do not fit in this building's free space: it "
                             f"holds {fits} walking; give --people {fits} or fewer.")


def for_scene(config: PeopleConfig, ground_truth: GridMap) -> PeopleConfig:
    """``config`` with its count for this building: a density's share of the floor a person
    can walk (rounded), or the count as given."""
    if config.density <= 0:
        return config
    clearance = cv2.distanceTransform(ground_truth.free.astype(np.uint8), cv2.DIST_L2,
                                      cv2.DIST_MASK_PRECISE) * ground_truth.resolution
    guide = _GuideGrid(ground_truth, clearance, config.radius)
    area = guide.walkable.sum() * guide.cell_m ** 2
    return dataclasses.replace(config, count=int(round(config.density * area / 100.0)),
                               density=0.0)


def capacity(config: PeopleConfig, ground_truth: GridMap) -> int:
    """How many people of ``config``'s size the building's free space holds walking (one
    ``SPACE_PER_PERSON_M`` square each, on the cells a person fits in)."""
    clearance = cv2.distanceTransform(ground_truth.free.astype(np.uint8), cv2.DIST_L2,
                                      cv2.DIST_MASK_PRECISE) * ground_truth.resolution
    return _GuideGrid(ground_truth, clearance, config.radius).capacity(config.radius)


class _GuideGrid:
    """The coarse grid people are guided on: the cells a person's disc fits in (clearance
    at least its radius), 8-connected, and geodesic distance fields over it."""

    def __init__(self, ground_truth: GridMap, clearance: np.ndarray, radius: float) -> None:
        k = max(1, int(round(GUIDE_CELL_M / ground_truth.resolution)))
        rows, cols = -(-ground_truth.shape[0] // k), -(-ground_truth.shape[1] // k)
        padded = np.zeros((rows * k, cols * k), np.float32)
        padded[:clearance.shape[0], :clearance.shape[1]] = clearance
        # A coarse cell is walkable where its centre has room for the disc and a margin:
        # routes keep off the walls, so that a person pulled round a corner clears it.
        centre = padded[k // 2::k, k // 2::k][:rows, :cols]
        self.walkable = centre >= radius + GUIDE_MARGIN_M
        self.k, self.shape = k, (rows, cols)
        self.cell_m = ground_truth.resolution * k
        self.origin = np.array(ground_truth.origin[:2], float)
        index = -np.ones(self.shape, np.int64)
        cells = np.argwhere(self.walkable)
        index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
        self._index, self._cells = index, cells
        src, dst, w = [], [], []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            r2, c2 = cells[:, 0] + dr, cells[:, 1] + dc
            ok = (r2 >= 0) & (r2 < rows) & (c2 >= 0) & (c2 < cols)
            j = np.full(len(cells), -1)
            j[ok] = index[r2[ok], c2[ok]]
            ok &= j >= 0
            src.append(np.flatnonzero(ok))
            dst.append(j[ok])
            w.append(np.full(ok.sum(), math.hypot(dr, dc) * self.cell_m))
        s, d, wt = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
        n = len(cells)
        self._graph = csr_matrix((np.concatenate([wt, wt]), (np.concatenate([s, d]),
                                                            np.concatenate([d, s]))),
                                 shape=(n, n))
        self._components: np.ndarray | None = None

    def capacity(self, radius: float) -> int:
        """How many people the walkable space holds walking (``SPACE_PER_PERSON_M`` square
        each)."""
        area = self.walkable.sum() * self.cell_m ** 2
        return int(area // SPACE_PER_PERSON_M ** 2)

    def points(self, cells: np.ndarray) -> np.ndarray:
        return self.origin + (cells[:, ::-1] + 0.5) * self.cell_m

    def walkable_points(self) -> np.ndarray:
        return self.points(self._cells)

    def cell_of(self, xy: np.ndarray) -> tuple[int, int]:
        rows, cols = self.cells_of(np.asarray(xy, float).reshape(1, 2))
        return int(rows[0]), int(cols[0])

    def reachable_points(self, xy: np.ndarray) -> np.ndarray:
        """The walkable cells (centres) connected to the one at ``xy`` (or nearest it)."""
        if self._components is None:
            from scipy.sparse.csgraph import connected_components

            self._components = connected_components(self._graph, directed=False)[1]
        node = self._nearest_node(xy)
        if node < 0:
            return np.zeros((0, 2))
        return self.points(self._cells[self._components == self._components[node]])

    def _nearest_node(self, xy: np.ndarray) -> int:
        if len(self._cells) == 0:
            return -1
        r, c = self.cell_of(xy)
        node = self._index[r, c]
        if node >= 0:
            return int(node)
        d = np.hypot(self._cells[:, 0] - r, self._cells[:, 1] - c)
        return int(np.argmin(d))

    def distance_field(self, goal: np.ndarray) -> np.ndarray:
        """(rows, cols) geodesic distance (metres) from ``goal`` over the walkable cells
        (inf elsewhere)."""
        dist = dijkstra(self._graph, indices=self._nearest_node(goal))
        field = np.full(self.shape, np.inf)
        field[self._cells[:, 0], self._cells[:, 1]] = dist
        return field

    def next_points(self, field: np.ndarray) -> np.ndarray:
        """(rows, cols, 2) per cell the centre of the neighbouring cell of least ``field``
        below the cell's own (the first such in row-major order of the neighbourhood), NaN
        where none is below it: the way down the field."""
        rows, cols = self.shape
        padded = np.full((rows + 2, cols + 2), np.inf)
        padded[1:-1, 1:-1] = field
        offsets = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
        around = np.stack([padded[1 + dr:1 + dr + rows, 1 + dc:1 + dc + cols]
                           for dr, dc in offsets])
        best = np.argmin(around, axis=0)
        lower = np.take_along_axis(around, best[None], 0)[0] < field
        r, c = np.nonzero(lower)
        step = np.asarray(offsets)[best[r, c]]
        out = np.full((rows, cols, 2), np.nan)
        out[r, c] = self.points(np.column_stack([r + step[:, 0], c + step[:, 1]]))
        return out

    def cells_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (rows, cols) of the guidance cells of the points (n, 2), clipped to the
        grid."""
        c = np.floor((np.asarray(xy, float) - self.origin) / self.cell_m).astype(int)
        return (np.minimum(np.maximum(c[:, 1], 0), self.shape[0] - 1),
                np.minimum(np.maximum(c[:, 0], 0), self.shape[1] - 1))

__all__ = ["Crowd", "PeopleConfig", "capacity", "check_capacity", "for_scene"]
