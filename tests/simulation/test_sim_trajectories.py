import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots import omni
from teleop_force.simulation.trajectories import (
    DEFAULT_MARGIN_RAD,
    CartesianWaypoints,
    MultiSine,
    TimeWarped,
    Trajectory,
    friction_trajectory,
    omni_inverse_kinematics,
    palpation_trajectory,
    rigid_body_trajectory,
    slow_stretch_trajectory,
    teleoperation_trajectory,
)

T_LONG = np.arange(0.0, 240.0, 0.01)


def _all_trajectories() -> list[Trajectory]:
    return [
        rigid_body_trajectory(0),
        rigid_body_trajectory(7),
        *(friction_trajectory(mode, 1) for mode in ("equal", "opposite", "independent")),
        teleoperation_trajectory(0),
        teleoperation_trajectory(5),
        slow_stretch_trajectory(240.0, 2),
    ]


def test_trajectories_stay_inside_the_joint_ranges() -> None:
    for trajectory in _all_trajectories():
        q, _ = trajectory.sample(T_LONG)
        assert np.all(q >= omni.Q_MIN_RAD + DEFAULT_MARGIN_RAD - 1e-12)
        assert np.all(q <= omni.Q_MAX_RAD - DEFAULT_MARGIN_RAD + 1e-12)
    palpation = palpation_trajectory(60.0, 2)
    q, _ = palpation.sample(np.arange(0.0, 60.0, 0.01))
    assert np.all(q >= omni.Q_MIN_RAD) and np.all(q <= omni.Q_MAX_RAD)


def test_velocities_are_the_derivatives_of_the_positions() -> None:
    t = np.arange(0.0, 20.0, 1e-3)
    for trajectory in [*_all_trajectories(), palpation_trajectory(20.0, 0)]:
        q, qd = trajectory.sample(t)
        numeric = np.gradient(q, t, axis=0)
        scale = np.max(np.abs(qd))
        assert np.max(np.abs(numeric[1:-1] - qd[1:-1])) < 2e-3 * scale + 1e-9


def test_trajectories_start_at_rest_and_scalar_time_works() -> None:
    for trajectory in [*_all_trajectories(), palpation_trajectory(10.0, 0)]:
        q0, qd0 = trajectory(0.0)
        assert q0.shape == (3,) and qd0.shape == (3,)
        np.testing.assert_allclose(qd0, 0.0, atol=1e-12)
        q_batch, _ = trajectory.sample(np.array([0.0, 3.3]))
        np.testing.assert_allclose(q_batch[1], trajectory.sample(3.3)[0])


def test_rigid_body_frequencies() -> None:
    trajectory = rigid_body_trajectory(0)
    frequencies = trajectory.frequencies_hz
    assert frequencies.shape == (3, 4)
    assert np.unique(frequencies).size == 12
    assert frequencies.min() >= 0.5 and frequencies.max() <= 2.0
    assert not np.array_equal(trajectory.phases_rad, rigid_body_trajectory(1).phases_rad)


def test_friction_modes() -> None:
    t = np.arange(0.0, 60.0, 0.01)
    centre = 0.5 * (omni.Q_MIN_RAD + omni.Q_MAX_RAD)
    for mode in ("equal", "opposite", "independent"):
        trajectory = friction_trajectory(mode, 3)
        assert trajectory.frequencies_hz.max() <= 0.7
        q, qd = trajectory.sample(t)
        if mode == "equal":
            np.testing.assert_allclose(qd[:, 1], qd[:, 2])
            np.testing.assert_allclose(q[:, 1] - centre[1], q[:, 2] - centre[2], atol=1e-12)
        elif mode == "opposite":
            np.testing.assert_allclose(qd[:, 1], -qd[:, 2])
            np.testing.assert_allclose(q[:, 1] - centre[1], centre[2] - q[:, 2], atol=1e-12)
        else:
            assert np.unique(trajectory.frequencies_hz).size == 12
            assert abs(np.corrcoef(qd[:, 1], qd[:, 2])[0, 1]) < 0.5
    with pytest.raises(ConfigurationError):
        friction_trajectory("sideways")


def test_teleoperation_is_seeded_random_and_band_limited() -> None:
    a, b = teleoperation_trajectory(0), teleoperation_trajectory(0)
    t = np.arange(0.0, 120.0, 0.01)
    np.testing.assert_array_equal(a.sample(t)[0], b.sample(t)[0])
    assert not np.array_equal(a.sample(t)[0], teleoperation_trajectory(1).sample(t)[0])
    q, _ = a.sample(t)
    spectrum = np.abs(np.fft.rfft(q - q.mean(axis=0), axis=0)) ** 2
    freqs = np.fft.rfftfreq(t.size, 0.01)
    assert np.sum(spectrum[freqs > 3.0]) < 0.01 * np.sum(spectrum)
    assert np.all(np.std(q, axis=0) > 0.15)  # it moves


def test_inverse_kinematics_round_trip() -> None:
    rng = np.random.default_rng(8)
    q = rng.uniform(omni.Q_MIN_RAD, omni.Q_MAX_RAD, (500, 3))
    r = omni.UPPER_ARM_LENGTH_M * np.cos(q[:, 1]) + omni.FOREARM_LENGTH_M * np.sin(q[:, 2])
    q = q[r > 0.01]  # the tip in front of the yaw axis (the Omni's workspace)
    p = np.array([omni.tip_position_formula(row) for row in q])
    np.testing.assert_allclose(omni_inverse_kinematics(p), q, atol=1e-9)
    with pytest.raises(DataError):
        omni_inverse_kinematics(np.array([0.0, 0.0, 0.5]))


def test_cartesian_waypoints_move_in_straight_lines() -> None:
    path = CartesianWaypoints(
        np.array([0.0, 1.0, 2.0]),
        np.array([[0.0, -0.04, 0.12], [0.0, -0.066, 0.12], [0.04, -0.066, 0.12]]),
    )
    t = np.linspace(1.0, 2.0, 50)
    p, _ = path.tip_sample(t)
    np.testing.assert_allclose(p[:, 1], -0.066)
    q, _ = path.sample(t)
    np.testing.assert_allclose(
        np.array([omni.tip_position_formula(row) for row in q]), p, atol=1e-12
    )
    _, qd_after = path.sample(5.0)
    np.testing.assert_allclose(qd_after, 0.0)
    with pytest.raises(ConfigurationError):
        CartesianWaypoints(np.array([0.0, 1.0]), np.array([[0.0, -0.04, 0.12], [0.0, 0.3, 0.0]]))
    with pytest.raises(ConfigurationError):
        CartesianWaypoints(np.array([1.0, 1.0]), np.zeros((2, 3)))


def test_multisine_validation() -> None:
    with pytest.raises(ConfigurationError):
        MultiSine(np.zeros(3), np.ones((3, 2)), np.ones((3, 3)), np.zeros((3, 2)))
    with pytest.raises(ConfigurationError):
        MultiSine(np.zeros(1), np.ones((1, 2)), -np.ones((1, 2)), np.zeros((1, 2)))
    with pytest.raises(DataError):
        rigid_body_trajectory().sample(np.zeros((2, 2)))


def test_time_warp_is_the_base_motion_slowed_in_its_stretches() -> None:
    base = teleoperation_trajectory(3)
    warped = TimeWarped(base, np.array([5.0, 20.0]), np.array([12.0, 26.0]), np.array([0.1, 0.5]))
    t = np.arange(0.0, 40.0, 1e-3)
    tau, rate = warped.warp(t)
    # rate 1 before the first stretch: the base motion itself
    early = t < 5.0
    np.testing.assert_array_equal(warped.sample(t[early])[0], base.sample(t[early])[0])
    # the held rate inside a stretch, 1 between and after them
    assert rate[(t > 5.6) & (t < 11.4)] == pytest.approx(0.1)
    assert rate[(t > 12.0) & (t < 20.0)] == pytest.approx(1.0)
    assert rate[(t > 20.6) & (t < 25.4)] == pytest.approx(0.5)
    # tau is the rate's integral (slow by (1 - r) times the stretch's depth area)
    np.testing.assert_allclose(np.gradient(tau, t)[1:-1], rate[1:-1], atol=1e-5)
    lost = 0.9 * (7.0 - 0.5) + 0.5 * (6.0 - 0.5)
    assert tau[-1] == pytest.approx(t[-1] - lost, abs=1e-9)
    # velocities are the positions' derivative (continuous across the ramps)
    q, qd = warped.sample(t)
    np.testing.assert_allclose(np.gradient(q, t, axis=0)[1:-1], qd[1:-1], atol=2e-4)
    q_scalar, qd_scalar = warped.sample(8.0)
    assert q_scalar.shape == (3,) and qd_scalar.shape == (3,)


def test_slow_stretches_hold_low_speeds() -> None:
    t = np.arange(0.0, 120.0, 1e-3)
    slow = slow_stretch_trajectory(120.0, 1)
    plain = teleoperation_trajectory(1)
    covered = (slow.ends_s - slow.starts_s).sum()
    assert covered == pytest.approx(0.4 * 120.0, abs=1e-6) and slow.starts_s[0] >= 3.0
    assert slow.ends_s[-1] <= 120.0 and np.all(slow.rates >= 0.02) and np.all(slow.rates <= 0.2)
    _, qd_slow = slow.sample(t)
    _, qd_plain = plain.sample(t)
    below = lambda qd: np.mean(np.abs(qd) < 0.05, axis=0)  # noqa: E731
    assert np.all(below(qd_slow) > below(qd_plain) + 0.15)
    assert slow_stretch_trajectory(120.0, 1, slow_fraction=0.0).starts_s.size == 0
    again = slow_stretch_trajectory(120.0, 1)
    np.testing.assert_array_equal(again.starts_s, slow.starts_s)


def test_time_warp_refuses_bad_stretches() -> None:
    base = teleoperation_trajectory(0)
    for starts, ends, rates in (
        ([1.0], [1.5], [0.1]),  # shorter than two ramps
        ([1.0, 3.0], [4.0, 6.0], [0.1, 0.1]),  # overlapping
        ([1.0], [4.0], [0.0]),  # rate 0
        ([1.0], [4.0], [1.5]),  # faster than the base
        ([1.0], [4.0, 6.0], [0.1]),  # shapes differ
    ):
        with pytest.raises(ConfigurationError):
            TimeWarped(base, np.array(starts), np.array(ends), np.array(rates))
    with pytest.raises(ConfigurationError):
        slow_stretch_trajectory(10.0, 0, slow_fraction=0.9)
    with pytest.raises(ConfigurationError):
        slow_stretch_trajectory(120.0, 0, rates=(0.3, 0.1))
