import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mjexplore.scenes.rectangles import cover_rectangles, rasterize_rectangles


@settings(max_examples=200, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 30), st.integers(1, 30))))
def test_cover_is_exact_and_disjoint(mask):
    rects = cover_rectangles(mask)
    assert np.array_equal(rasterize_rectangles(rects, mask.shape), mask)
    areas = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
    assert areas.sum() == mask.sum()  # Disjoint: no cell counted twice.


def test_thick_walls_become_one_box_each():
    mask = np.zeros((100, 200), bool)
    mask[:3, :] = mask[-3:, :] = True  # Two horizontal walls, 3 cells thick.
    mask[:, :3] = mask[:, -3:] = True  # Two vertical walls.
    mask[40:43, 50:150] = True  # A free-standing wall.
    assert len(cover_rectangles(mask)) <= 5
