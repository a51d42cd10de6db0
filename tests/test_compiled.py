"""The compiled views of flat buffers (teleop_force.compiled)."""

import numba
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.compiled import view_2d, view_3d


@numba.njit
def _view_2d_copy(buffer, offset, rows, cols):
    return view_2d(buffer, offset, rows, cols).copy()


@numba.njit
def _view_3d_copy(buffer, offset, d0, d1, d2):
    return view_3d(buffer, offset, d0, d1, d2).copy()


@numba.njit
def _write_through_2d(buffer, offset, rows, cols, value):
    view = view_2d(buffer, offset, rows, cols)
    view[rows - 1, cols - 1] = value


@given(
    offset=st.integers(0, 20),
    shape=st.tuples(st.integers(1, 4), st.integers(1, 4), st.integers(1, 4)),
)
@settings(max_examples=40, deadline=None)
def test_views_equal_numpy_reshape(offset, shape) -> None:
    buffer = np.arange(100.0)
    d0, d1, d2 = shape
    np.testing.assert_array_equal(
        _view_2d_copy(buffer, offset, d0, d1), buffer[offset : offset + d0 * d1].reshape(d0, d1)
    )
    np.testing.assert_array_equal(
        _view_3d_copy(buffer, offset, d0, d1, d2),
        buffer[offset : offset + d0 * d1 * d2].reshape(d0, d1, d2),
    )


def test_a_view_writes_into_its_buffer_and_works_for_ints() -> None:
    buffer = np.zeros(12)
    _write_through_2d(buffer, 2, 2, 3, 7.0)
    assert buffer[2 + 5] == 7.0
    assert np.count_nonzero(buffer) == 1
    ints = np.arange(12, dtype=np.int64)
    np.testing.assert_array_equal(_view_2d_copy(ints, 3, 3, 3), np.arange(3, 12).reshape(3, 3))
