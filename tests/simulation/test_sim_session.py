import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.simulation import (
    PlantConfig,
    SimulatedSession,
    friction_protocol,
    palpation_protocol,
    rigid_body_protocol,
    simulate_session,
    teleoperation_protocol,
)
from teleop_force.simulation.session import _ARRAY_FIELDS, slow_stretch_protocol
from teleop_force.simulation.trajectories import rigid_body_trajectory
from teleop_force.simulation.true_friction import TrueFriction


def test_sessions_are_reproducible() -> None:
    a = teleoperation_protocol(duration_s=0.5, seed=4)
    b = teleoperation_protocol(duration_s=0.5, seed=4)
    c = teleoperation_protocol(duration_s=0.5, seed=5)
    for name in ("q_rad", "tau_nm", "q_true_rad", "tau_applied_nm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.tau_nm, c.tau_nm)


def test_session_arrays_and_metadata() -> None:
    session = friction_protocol("opposite", duration_s=0.5, seed=1)
    assert session.n_samples == 500 and session.name == "friction-opposite"
    assert session.sample_interval_s == pytest.approx(1e-3)
    assert session.duration_s == pytest.approx(0.5)
    for array in (session.q_rad, session.tau_nm, session.f_tip_in_base_n, session.qd_true_rad_s):
        assert array.shape == (500, 3) and not array.flags.writeable
    np.testing.assert_array_equal(session.f_tip_in_base_n, 0.0)
    assert isinstance(session.friction, TrueFriction)
    np.testing.assert_allclose(
        session.tau_friction_true_nm, session.friction.torque(session.qd_true_rad_s)
    )
    columns = session.interchange_columns()
    assert list(columns) == ["t", "q1", "q2", "q3", "tau1", "tau2", "tau3", "f_x", "f_y", "f_z"]
    assert "f_x" not in session.interchange_columns(with_force=False)
    arrays: dict[str, np.ndarray] = {name: np.zeros((3, 3)) for name in _ARRAY_FIELDS}
    with pytest.raises(DataError):
        SimulatedSession(t_s=np.zeros(2), seed=0, **arrays)  # type: ignore[arg-type]


def test_frictionless_session_records_no_friction() -> None:
    session = rigid_body_protocol(duration_s=0.3, seed=0, plant_config=PlantConfig().ideal())
    assert session.friction is None
    np.testing.assert_array_equal(session.tau_friction_true_nm, 0.0)
    np.testing.assert_array_equal(session.q_rad, session.q_true_rad)  # no quantization


def test_palpation_presses_slides_and_releases() -> None:
    session = palpation_protocol(duration_s=9.0, seed=0)
    force = session.f_tip_in_base_n
    in_contact = np.any(force != 0.0, axis=1)
    assert 0.2 < in_contact.mean() < 0.8
    assert not in_contact[:1000].any()  # starts above the tissue
    assert force[:, 1].min() < -1.2  # pressing: f_y < 0, about k * depth
    assert np.all(force[:, 1] <= 0.0)
    assert np.max(np.hypot(force[:, 0], force[:, 2])) > 0.05  # sliding drag
    assert not in_contact[-300:].any()  # released


def test_invalid_arguments() -> None:
    trajectory = rigid_body_trajectory()
    with pytest.raises(ConfigurationError):
        simulate_session(trajectory, duration_s=0.0)
    with pytest.raises(ConfigurationError):
        simulate_session(trajectory, duration_s=0.1, seed=-1)
    with pytest.raises(ConfigurationError):
        simulate_session(trajectory, duration_s=0.1, effects=("cogging",))  # type: ignore[arg-type]


def test_slow_stretch_protocol_is_free_motion_with_slow_stretches() -> None:
    session = slow_stretch_protocol(duration_s=12.0, seed=2, slow_fraction=0.4)
    assert session.name == "slow-stretch" and session.contact is None
    assert not np.any(session.f_tip_in_base_n)
    plain = teleoperation_protocol(duration_s=12.0, seed=2)
    # the same motion until the first stretch (>= 3 s), then slower
    early = session.t_s < 3.0
    np.testing.assert_allclose(session.q_ref_rad[early], plain.q_ref_rad[early])
    speed = np.abs(session.qd_ref_rad_s).mean()
    assert speed < 0.9 * np.abs(plain.qd_ref_rad_s).mean()
    assert session.family == "one"
