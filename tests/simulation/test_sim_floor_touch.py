import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.simulation import FloorTouchTrajectory, floor_touch_trajectory


def test_velocities_are_the_derivatives_of_the_positions() -> None:
    trajectory = floor_touch_trajectory(5, duration_s=30.0)
    t = np.linspace(0.0, 30.0, 30001)
    p, v = trajectory.tip_sample(t)
    np.testing.assert_allclose(np.gradient(p, t, axis=0)[1:-1], v[1:-1], atol=2e-4)
    q, qd = trajectory.sample(t)
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[1:-1], qd[1:-1], atol=5e-3)
    assert q.shape == (t.size, 3)


def test_presses_below_the_surface_and_holds_still() -> None:
    trajectory = floor_touch_trajectory(2, duration_s=60.0, surface_y_m=-0.05)
    t = np.linspace(0.0, 60.0, 60001)
    p, v = trajectory.tip_sample(t)
    below = p[:, 1] < -0.05
    assert 0.15 < below.mean() < 0.45 and not below[t < 2.0].any()
    starts, ends = trajectory.still_starts_s, trajectory.still_ends_s
    assert starts.size >= 4
    for start, end in zip(starts, ends, strict=True):
        plateau = (t > start + trajectory.still_ramp_s) & (t < end)
        np.testing.assert_allclose(v[plateau], 0.0, atol=1e-12)
    other = floor_touch_trajectory(3, duration_s=60.0)
    assert not np.allclose(other.tip_sample(t)[0], floor_touch_trajectory(2).tip_sample(t)[0])


def test_invalid_trajectories() -> None:
    k = np.ones((2, 3))
    with pytest.raises(ConfigurationError):
        FloorTouchTrajectory(np.ones((3, 3)), k, k, np.array([0.0, 1.0]), np.zeros(2))
    with pytest.raises(ConfigurationError):
        FloorTouchTrajectory(k, k, k, np.array([1.0, 0.0]), np.zeros(2))
    with pytest.raises(ConfigurationError):
        FloorTouchTrajectory(
            k, k, k, np.array([0.0, 9.0]), np.zeros(2), np.array([1.0, 2.0]), np.array([3.0, 4.0])
        )
    with pytest.raises(ConfigurationError):
        floor_touch_trajectory(0, bandwidth_hz=0.0)
