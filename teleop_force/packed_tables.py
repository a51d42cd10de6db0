"""Constant arrays packed into one float and one int buffer, and their views in compiled code.

At 1 kHz a compiled call costs ~70 ns per array argument in numba's dispatcher, so the
per-sample steps take their constant tables packed: :func:`pack` concatenates arrays (up to
3-D) into a float and an int buffer, with a header of ``(offset, shape)`` per slot at the
start of the int buffer, and :func:`slot_1d`, :func:`slot_2d`, :func:`slot_3d` cut a slot back
out as a view, at no cost (:func:`~teleop_force.compiled.view_2d`). Used by the fused
estimator step (:mod:`~teleop_force.estimation.fused_step`) and the count observer
(:mod:`~teleop_force.estimation.count_observer`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from teleop_force.compiled import njit_cached, view_2d, view_3d

#: Entries per slot in a header: offset, then three dimensions (unused ones are 1).
HEADER_WIDTH = 4


def pack(
    float_arrays: Sequence[np.ndarray], int_arrays: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Pack arrays (up to 3-D) into ``(floats, ints)``; ``ints`` starts with the header.

    The header holds ``HEADER_WIDTH`` entries per slot, float slots first: the offset in its
    buffer (the int offsets count from the buffer's start, header included) and the shape.
    """
    n_slots = len(float_arrays) + len(int_arrays)
    header = np.zeros(HEADER_WIDTH * n_slots, dtype=np.int64)
    chunks_f: list[np.ndarray] = []
    chunks_i: list[np.ndarray] = [header]
    offset_f = 0
    offset_i = header.size
    for slot, array in enumerate([*float_arrays, *int_arrays]):
        is_float = slot < len(float_arrays)
        a = np.asarray(array, dtype=float if is_float else np.int64)
        if a.ndim > 3:
            raise ValueError(f"slot {slot}: at most 3 dimensions, got {a.ndim}")
        shape = (*a.shape, 1, 1, 1)[:3]
        header[HEADER_WIDTH * slot] = offset_f if is_float else offset_i
        header[HEADER_WIDTH * slot + 1 : HEADER_WIDTH * slot + 4] = shape
        flat = a.reshape(-1)
        if is_float:
            chunks_f.append(flat)
            offset_f += flat.size
        else:
            chunks_i.append(flat)
            offset_i += flat.size
    floats = np.ascontiguousarray(np.concatenate(chunks_f) if chunks_f else np.zeros(0))
    ints = np.ascontiguousarray(np.concatenate(chunks_i), dtype=np.int64)
    return floats, ints


@njit_cached(inline="always")
def slot_size(ints: np.ndarray, slot: int) -> int:  # pragma: no cover - compiled
    """Entries of ``slot``."""
    h = HEADER_WIDTH * slot
    return int(ints[h + 1] * ints[h + 2] * ints[h + 3])


@njit_cached(inline="always")
def slot_1d(buffer: np.ndarray, ints: np.ndarray, slot: int) -> np.ndarray:  # pragma: no cover
    """``slot`` of ``buffer``, flat."""
    o = ints[HEADER_WIDTH * slot]
    return buffer[o : o + slot_size(ints, slot)]


@njit_cached(inline="always")
def slot_2d(buffer: np.ndarray, ints: np.ndarray, slot: int) -> np.ndarray:  # pragma: no cover
    """``slot`` of ``buffer`` as a 2-D view."""
    h = HEADER_WIDTH * slot
    return view_2d(buffer, ints[h], ints[h + 1], ints[h + 2])


@njit_cached(inline="always")
def slot_3d(buffer: np.ndarray, ints: np.ndarray, slot: int) -> np.ndarray:  # pragma: no cover
    """``slot`` of ``buffer`` as a 3-D view."""
    h = HEADER_WIDTH * slot
    return view_3d(buffer, ints[h], ints[h + 1], ints[h + 2], ints[h + 3])
