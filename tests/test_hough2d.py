"""2-D Hough: the paper's algorithm against brute force, and Ballard's R-table on images."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from mks_sim.errors import DataError
from mks_sim.models.hough2d import GeneralizedHough2D, RTableHough, edges_and_gradients


def test_accumulate_is_e_plus_d_brute_force() -> None:
    rng = np.random.default_rng(0)
    B = rng.integers(-3, 4, (5, 2))
    E = rng.integers(0, 10, (7, 2))
    h = GeneralizedHough2D(B, reference=(0, 0))
    acc, off = h.accumulate(E, shape=(10, 10))
    ref = np.zeros((10, 10), int)
    n_off = 0
    for e in E:
        for b in B:
            x, y = e - b  # displacement = reference - boundary point
            if 0 <= x < 10 and 0 <= y < 10:
                ref[y, x] += 1
            else:
                n_off += 1
    np.testing.assert_array_equal(acc, ref)
    assert off == n_off and acc.sum() + off == len(E) * len(B)


def test_single_shape_maximum_at_reference() -> None:
    # A translated shape: the reference point collects one vote per boundary point.
    B = np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [2, 2], [-2, 1]])
    h = GeneralizedHough2D(B)
    acc, _ = h.accumulate(B + [10, 7], shape=(20, 20))
    top, cells = h.maxima(acc)
    assert top == len(B)
    np.testing.assert_array_equal(cells, [[10, 7]])


def test_figure_2_2_model() -> None:
    h = GeneralizedHough2D([(1, 0), (0, 1), (-1, 0), (0, -1)])
    np.testing.assert_array_equal(h.displacements, [(-1, 0), (0, -1), (1, 0), (0, 1)])


def _render(poly: np.ndarray, shape=(200, 260)) -> np.ndarray:
    img = np.zeros(shape, np.uint8)
    cv2.fillPoly(img, [np.round(poly).astype(np.int32)], 200)
    return img


@pytest.mark.parametrize(
    ("angle", "scale", "t"), [(0.0, 1.0, (150.0, 90.0)), (30.0, 1.2, (140.0, 110.0))]
)
def test_rtable_finds_rotated_scaled_shape(angle: float, scale: float, t) -> None:
    poly = np.array([[0, 0], [60, 0], [60, 15], [20, 15], [20, 40], [35, 40], [35, 55], [0, 55]])
    poly = poly + 50.0
    ref = np.array([80.0, 80.0])
    rt = RTableHough.from_image(_render(poly), reference=ref)
    th = np.radians(angle)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    scene = _render((poly - ref) @ R.T * scale + np.asarray(t))
    best = rt.detect_image(scene, rotations_deg=[0, 15, 30, 45], scales=[0.8, 1.0, 1.2], n_best=1)[
        0
    ]
    assert best.angle_deg == pytest.approx(angle)
    assert best.scale == pytest.approx(scale)
    assert np.hypot(best.position[0] - t[0], best.position[1] - t[1]) < 3.0


def test_rtable_bins_by_gradient() -> None:
    pts, ang = edges_and_gradients(_render(np.array([[20, 20], [80, 20], [80, 60], [20, 60]])))
    rt = RTableHough(pts, ang, n_bins=4)
    # An axis-aligned rectangle: gradients point along +-x, +-y; each edge lands in some bin.
    assert sum(len(t) for t in rt.table) == len(pts)


def test_errors() -> None:
    with pytest.raises(DataError, match=r"\(N, 2\)"):
        GeneralizedHough2D(np.zeros((3, 3)))
    with pytest.raises(DataError, match="angles"):
        RTableHough(np.zeros((3, 2)), np.zeros(2))
    with pytest.raises(DataError, match="image"):
        edges_and_gradients(np.zeros((0,)))
