import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from mjexplore.topology.graph import build_graph
from mjexplore.topology.gvd import DynamicGVD


def full(obstacles):
    gvd = DynamicGVD(obstacles.shape)
    gvd.update(obstacles)
    return gvd


def closed_box(rows, cols):
    obst = np.zeros((rows, cols), bool)
    obst[0, :] = obst[-1, :] = obst[:, 0] = obst[:, -1] = True
    return obst


changes = st.lists(st.tuples(st.integers(0, 23), st.integers(0, 31), st.integers(1, 6),
                             st.integers(1, 6), st.booleans()), min_size=1, max_size=12)


@settings(max_examples=150, deadline=None)
@given(steps=st.lists(changes, min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_incremental_update_equals_recomputation(steps, seed):
    rng = np.random.default_rng(seed)
    obst = closed_box(24, 32)
    obst |= rng.random(obst.shape) < 0.05
    gvd = full(obst)
    for batch in steps:
        for r, c, h, w, value in batch:
            obst[r:r + h, c:c + w] = value
        gvd.update(obst)
        fresh = full(obst)
        assert np.array_equal(gvd.distance2, fresh.distance2)
        assert np.array_equal(gvd.nearest, fresh.nearest)
        assert np.array_equal(gvd.voronoi, fresh.voronoi)


def test_incremental_update_with_reported_cells_only():
    obst = closed_box(40, 60)
    gvd = full(obst)
    obst[10:20, 20:25] = True
    changed = np.flatnonzero((obst & ~gvd.occupied.astype(bool)).reshape(-1))
    gvd.update(obst, cells=changed)
    assert np.array_equal(gvd.voronoi, full(obst).voronoi)


def test_distances_match_exact_edt_within_a_cell():
    rng = np.random.default_rng(1)
    obst = closed_box(80, 100) | (rng.random((80, 100)) < 0.02)
    gvd = full(obst)
    exact = ndimage.distance_transform_edt(~obst)
    assert np.abs(np.sqrt(gvd.distance2) - exact).max() < 1.0
    nearest = gvd.nearest
    r, c = np.divmod(nearest, obst.shape[1])
    assert obst[r, c].all()  # Every cell refers to a real obstacle.


def test_gvd_cells_are_equidistant_to_two_obstacles():
    rng = np.random.default_rng(2)
    obst = closed_box(60, 80)
    for _ in range(12):
        r, c = rng.integers(5, 55), rng.integers(5, 75)
        obst[r:r + rng.integers(2, 8), c:c + rng.integers(2, 8)] = True
    gvd = full(obst)
    obstacles = np.argwhere(obst)
    labels, _ = ndimage.label(obst, structure=np.ones((3, 3)))
    cells = np.argwhere(gvd.voronoi)
    assert len(cells) > 50
    for cell in cells:
        d = np.hypot(*(obstacles - cell).T)
        nearest = d.min()
        # Two distinct obstacles (different connected obstacle bodies, or cells of one
        # body far apart) lie within one cell of the nearest distance.
        close = obstacles[d <= nearest + 1.0]
        spread = np.abs(close[:, None, :] - close[None, :, :]).max(axis=2).max()
        assert spread > 1 or len(np.unique(labels[tuple(close.T)])) > 1


def graph_of(obst):
    gvd = full(obst)
    return build_graph(gvd.voronoi, gvd.distance2, ~obst, 0.05)


def degrees(graph):
    return np.bincount(graph.edges.ravel(), minlength=len(graph.positions))


def test_corridor_gives_a_single_path_along_its_middle():
    obst = np.ones((30, 200), bool)
    obst[10:20, 5:195] = False  # A 0.5 m wide, 9.5 m long corridor.
    graph = graph_of(obst)
    deg = degrees(graph)
    assert (deg == 1).sum() == 2 and (deg >= 3).sum() == 0
    assert np.abs(graph.positions[:, 0] - 14.5).max() <= 1.0
    assert graph.lengths.max() <= 2.0 / 0.05 + 1e-9
    assert len(graph.edges) == len(graph.positions) - 1


def test_loop_gives_one_cycle():
    obst = np.ones((120, 160), bool)
    obst[10:110, 10:150] = False
    obst[35:85, 35:125] = True  # The solid core of a ring corridor.
    graph = graph_of(obst)
    deg = degrees(graph)
    assert (deg == 1).sum() == 0  # Corner spurs are pruned.
    assert len(graph.edges) == len(graph.positions)  # Connected with exactly one cycle.
    assert (deg == 2).all()


def test_t_junction_gives_one_branch_point():
    obst = np.ones((140, 200), bool)
    obst[10:30, 10:190] = False  # The bar of the T.
    obst[10:130, 90:110] = False  # Its stem.
    graph = graph_of(obst)
    deg = degrees(graph)
    assert (deg == 3).sum() == 1 and (deg == 1).sum() == 3
    junction = graph.positions[deg == 3][0]
    assert abs(junction[1] - 99.5) < 3 and junction[0] < 35


@settings(max_examples=100, deadline=None)
@given(steps=st.lists(st.tuples(changes, changes), min_size=1, max_size=4),
       seed=st.integers(0, 2**32 - 1))
def test_incremental_update_with_a_domain_equals_recomputation(steps, seed):
    """Obstacles and the known region (the field's domain) both change, as in exploration."""
    rng = np.random.default_rng(seed)
    obst = rng.random((24, 32)) < 0.05
    domain = np.zeros((24, 32), bool)
    domain[8:16, 10:20] = True
    gvd = DynamicGVD(obst.shape)
    gvd.update(obst, domain)
    for obstacle_batch, domain_batch in steps:
        for r, c, h, w, value in obstacle_batch:
            obst[r:r + h, c:c + w] = value
        for r, c, h, w, value in domain_batch:
            domain[r:r + h, c:c + w] = value
        gvd.update(obst, domain)
        fresh = DynamicGVD(obst.shape)
        fresh.update(obst, domain)
        assert np.array_equal(gvd.distance2, fresh.distance2)
        assert np.array_equal(gvd.nearest, fresh.nearest)
        assert np.array_equal(gvd.voronoi, fresh.voronoi)
        outside = ~(domain | obst)
        assert (gvd.nearest[outside] == -1).all()
