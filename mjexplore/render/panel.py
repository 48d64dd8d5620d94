"""The 2D panel of a video frame: the map as the robot knows it, with its topology.

Image conventions: RGB uint8, north (+y) up, the map scaled uniformly to fit the panel
and centred on a dark background.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from mjexplore.maps import GridMap

UNKNOWN = (128, 128, 128)
FREE = (255, 255, 255)
OCCUPIED = (0, 0, 0)
BACKGROUND = (40, 40, 40)
VORONOI = (120, 170, 255)
TRAJECTORY = (30, 90, 220)
PATH = (20, 170, 40)
GOAL = (230, 30, 30)
EDGE = (240, 150, 30)
ROBOT = (20, 200, 20)
OTHER_NODE = (200, 40, 40)
PERSON = (199, 41, 161)  # A pedestrian's disc: the colour of its body in the 3D view.
PERSON_OUTLINE = (80, 0, 60)
# A team's other robots (robot 1, 2, ...): body, trajectory and path in one hue each.
TEAMMATE_COLOURS = ((230, 120, 20), (160, 60, 200), (20, 170, 190), (200, 60, 130),
                    (140, 110, 60), (90, 90, 230), (180, 180, 30))


@dataclasses.dataclass
class RobotOverlay:
    """A teammate as a panel draws it (``map`` frame, metres).

    Attributes:
        pose: (x, y, yaw).
        trajectory: (k, 2) driven path or None.
        goal: (x, y) or None.
        path: (k, 2) planned path or None.
    """

    pose: np.ndarray
    trajectory: np.ndarray | None = None
    goal: np.ndarray | None = None
    path: np.ndarray | None = None


@dataclasses.dataclass
class PanelContent:
    """What a panel shows (all positions in the ``map`` frame, metres).

    Attributes:
        grid: The map.
        gvd_segments: (m, 2, 2) segments of the GVD graph (pruned, as the TER uses it).
        ter_positions, ter_edges, ter_flags: TER nodes (n, 2), edges (m, 2), flags (n,).
        frontier_cells: List of (k, 2) (row, col) arrays, one per frontier.
        frontier_gains: Information gain of each frontier (coloured, viridis, 0..max).
        goal: (x, y) or None.
        path: (k, 2) planned path or None.
        trajectory: (k, 2) driven path or None.
        pose: (x, y, yaw) or None.
        text: Lines written at the top left.
        teammates: A team's other robots, each in a colour of its own
            (``TEAMMATE_COLOURS``); the fields above are robot 0's.
        people: (n, 2) pedestrians' true positions (filled discs of ``people_radius``
            metres in ``PERSON``, over the map and the paths, under the goals and the
            robots), or None.
        people_radius: A pedestrian's radius, metres.
    """

    grid: GridMap
    gvd_segments: np.ndarray | None = None
    ter_positions: np.ndarray | None = None
    ter_edges: np.ndarray | None = None
    ter_flags: np.ndarray | None = None
    frontier_cells: list | None = None
    frontier_gains: np.ndarray | None = None
    goal: np.ndarray | None = None
    path: np.ndarray | None = None
    trajectory: np.ndarray | None = None
    pose: np.ndarray | None = None
    text: tuple[str, ...] = ()
    teammates: tuple[RobotOverlay, ...] = ()
    people: np.ndarray | None = None
    people_radius: float = 0.25


class PanelLayout:
    """Where the map lands in a panel of ``width`` x ``height`` pixels."""

    def __init__(self, grid: GridMap, width: int, height: int, margin: int = 4) -> None:
        rows, cols = grid.shape
        self.scale = min((width - 2 * margin) / cols, (height - 2 * margin) / rows)
        self.map_w = max(1, int(round(cols * self.scale)))
        self.map_h = max(1, int(round(rows * self.scale)))
        self.x0 = (width - self.map_w) // 2
        self.y0 = (height - self.map_h) // 2
        self.grid = grid

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(k, 2) map-frame metres -> (k, 2) integer pixel (x, y)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        g = self.grid
        col = (xy[:, 0] - g.origin[0]) / g.resolution
        row_from_top = g.shape[0] - (xy[:, 1] - g.origin[1]) / g.resolution
        return np.column_stack([self.x0 + col * self.scale,
                                self.y0 + row_from_top * self.scale]).round().astype(np.int32)

    def cells_to_pixels(self, rc: np.ndarray) -> np.ndarray:
        """(k, 2) (row, col) -> pixel (x, y) of the cell centres."""
        rc = np.asarray(rc, float).reshape(-1, 2)
        return np.column_stack([self.x0 + (rc[:, 1] + 0.5) * self.scale,
                                self.y0 + (self.grid.shape[0] - rc[:, 0] - 0.5) * self.scale]
                               ).astype(np.int32)


def _polyline(img, layout: PanelLayout, xy, colour, thickness: int) -> None:
    if xy is not None and len(xy) > 1:
        cv2.polylines(img, [layout.to_pixels(xy)], False, colour, thickness, cv2.LINE_AA)


def _robot_marker(img, layout: PanelLayout, pose, size: float, colour) -> None:
    """A triangle at ``pose`` (x, y, yaw) pointing along its heading, ``size`` metres."""
    x, y, yaw = pose
    tri = np.array([[x + size * np.cos(yaw), y + size * np.sin(yaw)],
                    [x + size * np.cos(yaw + 2.5), y + size * np.sin(yaw + 2.5)],
                    [x + size * np.cos(yaw - 2.5), y + size * np.sin(yaw - 2.5)]])
    cv2.fillPoly(img, [layout.to_pixels(tri)], colour, cv2.LINE_AA)


def _people(img, layout: PanelLayout, xy, radius: float) -> None:
    """Filled, outlined discs of ``radius`` metres (at least 4 pixels, so that a person
    stands out at any zoom) at ``xy`` (k, 2)."""
    r = max(4, int(round(radius / layout.grid.resolution * layout.scale)))
    for p in layout.to_pixels(xy):
        centre = (int(p[0]), int(p[1]))
        cv2.circle(img, centre, r, PERSON, -1, cv2.LINE_AA)
        cv2.circle(img, centre, r, PERSON_OUTLINE, 1, cv2.LINE_AA)


def render_panel(content: PanelContent, width: int, height: int) -> np.ndarray:
    """The panel image (height, width, 3) RGB uint8."""
    img = np.empty((height, width, 3), np.uint8)
    img[:] = BACKGROUND
    layout = PanelLayout(content.grid, width, height)
    data = content.grid.data
    cells = np.empty(data.shape + (3,), np.uint8)
    cells[:] = UNKNOWN
    cells[data == 0] = FREE
    cells[data > 0] = OCCUPIED
    if content.frontier_cells:
        gains = np.asarray(content.frontier_gains if content.frontier_gains is not None
                           else np.ones(len(content.frontier_cells)), float)
        top = max(float(gains.max()), 1e-9) if len(gains) else 1.0
        lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_VIRIDIS)
        for fc, g in zip(content.frontier_cells, gains):
            bgr = lut[int(np.clip(g / top, 0, 1) * 255), 0]
            cells[fc[:, 0], fc[:, 1]] = bgr[::-1]
    view = cv2.resize(cells[::-1], (layout.map_w, layout.map_h), interpolation=cv2.INTER_NEAREST)
    img[layout.y0:layout.y0 + layout.map_h, layout.x0:layout.x0 + layout.map_w] = view
    thick = max(1, int(round(layout.scale * 2)))
    if content.gvd_segments is not None and len(content.gvd_segments):
        seg = layout.to_pixels(np.asarray(content.gvd_segments).reshape(-1, 2)).reshape(-1, 2, 2)
        cv2.polylines(img, list(seg), False, VORONOI, max(1, thick // 2 + 1), cv2.LINE_AA)
    _polyline(img, layout, content.trajectory, TRAJECTORY, thick)
    if content.ter_positions is not None and len(content.ter_positions):
        px = layout.to_pixels(content.ter_positions)
        for a, b in np.asarray(content.ter_edges, int).reshape(-1, 2):
            cv2.line(img, tuple(map(int, px[a])), tuple(map(int, px[b])), EDGE, 1, cv2.LINE_AA)
        flags = content.ter_flags if content.ter_flags is not None else np.full(len(px), -1.0)
        radius = max(2, thick + 1)
        for p, f in zip(px, flags):
            colour = ROBOT if f == 0 else (EDGE if f == 1 else OTHER_NODE)
            cv2.circle(img, tuple(map(int, p)), radius, colour, -1, cv2.LINE_AA)
    _polyline(img, layout, content.path, PATH, thick)
    if content.people is not None and len(content.people):
        _people(img, layout, content.people, content.people_radius)
    if content.goal is not None:
        g = tuple(map(int, layout.to_pixels(content.goal)[0]))
        cv2.drawMarker(img, g, GOAL, cv2.MARKER_STAR, max(10, 6 * thick), 2)
    size = max(0.35, 6 / layout.scale * content.grid.resolution)
    for k, mate in enumerate(content.teammates):
        colour = TEAMMATE_COLOURS[k % len(TEAMMATE_COLOURS)]
        _polyline(img, layout, mate.trajectory, colour, max(1, thick // 2))
        _polyline(img, layout, mate.path, colour, thick)
        if mate.goal is not None:
            g = tuple(map(int, layout.to_pixels(mate.goal)[0]))
            cv2.drawMarker(img, g, colour, cv2.MARKER_STAR, max(10, 6 * thick), 2)
        _robot_marker(img, layout, mate.pose, size, colour)
    if content.pose is not None:
        _robot_marker(img, layout, content.pose, size, ROBOT)
    if content.text:
        width_px = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, 0.5, 1)[0][0]
                       for t in content.text)
        box = img[:8 + 20 * len(content.text), :width_px + 14]
        box[:] = (box * 0.3).astype(np.uint8)
        for i, line in enumerate(content.text):
            cv2.putText(img, line, (6, 18 + 20 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                        (255, 255, 255), 1, cv2.LINE_AA)
    return img


def gvd_segments(graph, grid: GridMap) -> np.ndarray:
    """(m, 2, 2) map-frame segments of a :class:`~mjexplore.topology.graph.GvdGraph`."""
    if not len(graph.edges):
        return np.zeros((0, 2, 2))
    rc = graph.positions[np.asarray(graph.edges)]  # (m, 2, 2) (row, col)
    xy = np.stack([grid.origin[0] + (rc[..., 1] + 0.5) * grid.resolution,
                   grid.origin[1] + (rc[..., 0] + 0.5) * grid.resolution], axis=-1)
    return xy
