import threading

import numpy as np
import pytest

from web.buffers import RingBuffer, bin_mean


def test_ring_keeps_the_newest_rows_in_order_after_wrapping():
    ring = RingBuffer(capacity=5, width=2)
    assert len(ring) == 0 and ring.latest() is None
    for i in range(8):
        ring.append(float(i), (i, 10 * i))
    window = ring.window()
    assert len(ring) == 5 == len(window)
    np.testing.assert_array_equal(window.t_s, [3, 4, 5, 6, 7])
    np.testing.assert_array_equal(window.values[:, 1], [30, 40, 50, 60, 70])
    t, row = ring.latest()
    assert t == 7.0 and row.tolist() == [7.0, 70.0]


def test_window_from_a_time_and_copies_not_views():
    ring = RingBuffer(capacity=100, width=1)
    for i in range(10):
        ring.append(i * 0.1, (i,))
    window = ring.window(0.45)
    np.testing.assert_allclose(window.t_s, [0.5, 0.6, 0.7, 0.8, 0.9])
    window.values[:] = -1
    assert ring.window().values[5, 0] == 5
    ring.clear()
    assert len(ring.window()) == 0


def test_ring_rejects_bad_sizes_and_rows():
    with pytest.raises(ValueError):
        RingBuffer(0, 1)
    ring = RingBuffer(4, 3)
    with pytest.raises(ValueError):
        ring.append(0.0, (1.0, 2.0))


def test_concurrent_appends_are_all_counted():
    ring = RingBuffer(capacity=10_000, width=1)

    def writer(offset):
        for i in range(2000):
            ring.append(float(offset + i), (1.0,))

    threads = [threading.Thread(target=writer, args=(k * 10_000,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert len(ring) == 8000
    assert np.all(ring.window().values == 1.0)


def test_bin_mean_averages_per_bin_and_marks_empty_bins_nan():
    t = np.array([0.05, 0.1, 0.15, 0.55, 2.0, -1.0])
    v = np.array([[1.0, 10.0], [3.0, np.nan], [5.0, 30.0], [7.0, 70.0], [9.0, 9.0], [8.0, 8.0]])
    centres, out = bin_mean(t, v, 0.0, 1.0, 4)
    np.testing.assert_allclose(centres, [0.125, 0.375, 0.625, 0.875])
    np.testing.assert_allclose(out[0], [3.0, 20.0])  # NaN ignored in the mean
    assert np.all(np.isnan(out[1])) and np.all(np.isnan(out[3]))
    np.testing.assert_allclose(out[2], [7.0, 70.0])


def test_bin_mean_decimates_1khz_to_a_few_hundred_points():
    t = np.arange(10_000) * 1e-3
    v = np.sin(t)[:, None]
    centres, out = bin_mean(t, v, 0.0, 10.0, 300)
    assert centres.shape == (300,) and out.shape == (300, 1)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[:, 0], np.sin(centres), atol=2e-3)


def test_bin_mean_rejects_bad_arguments():
    with pytest.raises(ValueError):
        bin_mean(np.zeros(2), np.zeros((2, 1)), 1.0, 1.0, 3)
    with pytest.raises(ValueError):
        bin_mean(np.zeros(2), np.zeros((3, 1)), 0.0, 1.0, 3)
    with pytest.raises(ValueError):
        bin_mean(np.zeros(2), np.zeros((2, 1)), 0.0, 1.0, 0)


def test_bin_mean_handles_unsorted_times_and_matches_a_reference():
    rng = np.random.default_rng(3)
    t = rng.uniform(-1.0, 11.0, 5000)
    v = rng.normal(size=(5000, 4))
    v[rng.uniform(size=v.shape) < 0.1] = np.nan
    centres, out = bin_mean(t, v, 0.0, 10.0, 37)
    width = 10.0 / 37
    for b in (0, 5, 36):
        sel = (t >= b * width) & (t < (b + 1) * width)
        np.testing.assert_allclose(out[b], np.nanmean(v[sel], axis=0))
    assert np.isclose(centres[0], width / 2)
    _, empty = bin_mean(np.array([20.0]), np.ones((1, 2)), 0.0, 1.0, 5)
    assert np.all(np.isnan(empty))
