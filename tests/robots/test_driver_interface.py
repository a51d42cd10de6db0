"""The driver interface: sawSensablePhantom's conventions, round trips, virtual work, checks."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from teleop_force.errors import DataError, ModelError
from teleop_force.robots.driver_check import check_efforts, check_positions
from teleop_force.robots.driver_interface import (
    DriverInterface,
    EffortEntry,
    PositionEntry,
    effort_coupling_conjugate_to_positions,
)
from teleop_force.robots.file import load_driver_interface, load_robot_description
from teleop_force.robots.omni import (
    OMNI_COUPLING,
    Q_MAX_RAD,
    Q_MIN_RAD,
    tip_jacobian_formula,
    tip_position_formula,
)
from teleop_force.robots.registry import BUILTIN_DRIVERS, builtin_driver

BUILTIN = Path(__file__).parents[2] / "teleop_force" / "robots" / "drivers"
NAMES = ("waist", "shoulder", "elbow", "yaw", "pitch", "roll")
#: OpenHaptics' device frame is not centred where the model's joints 1 and 2 meet.
OPENHAPTICS_ORIGIN_M = np.array([0.0, -0.11, -0.09])


def saw_measured_js(
    joint_angles: np.ndarray,
    gimbal_angles: np.ndarray,
    joint_torque: np.ndarray,
    gimbal_torque: np.ndarray,
    joint_scales: np.ndarray | None = None,
    joint_offsets: np.ndarray | None = None,
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """sawSensablePhantom's measured_js from raw OpenHaptics values, ported line by line.

    jhu-saw/sawSensablePhantom, core/components/code/mtsSensableHD.cpp at
    38dd0d68b8b24fd23bfbebfb2a8d57591ffcd2b2 (line numbers of that file).
    """
    # 116: m_joint_offsets.SetAll(0.0);   119: m_joint_scales.SetAll(1.0);
    scales = np.ones(6) if joint_scales is None else joint_scales
    offsets = np.zeros(6) if joint_offsets is None else joint_offsets
    position = np.zeros(6)
    effort = np.zeros(6)
    # 312: hdGetDoublev(HD_CURRENT_JOINT_ANGLES, device->m_measured_js.Position().Pointer());
    position[0:3] = joint_angles
    # 314: hdGetDoublev(HD_CURRENT_GIMBAL_ANGLES, device->GimbalPositionJointRef.Pointer());
    position[3:6] = gimbal_angles
    # 316: hdGetDoublev(HD_LAST_JOINT_TORQUE, device->m_measured_js.Effort().Pointer());
    effort[0:3] = joint_torque
    # 318: hdGetDoublev(HD_LAST_GIMBAL_TORQUE, device->GimbalEffortJointRef.Pointer());
    effort[3:6] = gimbal_torque
    # 397: device->m_measured_js.Position().ElementwiseMultiply(device->m_joint_scales);
    position = position * scales
    # 398: device->m_measured_js.Position().Add(device->m_joint_offsets);
    position = position + offsets
    # 418: device->m_measured_js.Position()[0] = -device->m_measured_js.Position()[0];
    position[0] = -position[0]
    # 419: device->m_measured_js.Position()[2] -= device->m_measured_js.Position()[1];
    position[2] -= position[1]
    # 421-423: device->m_measured_js.Position()[3] = device->m_measured_js.Position()[3]; ...
    return NAMES, position, effort


def random_raw(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Raw OpenHaptics joint angles [rad] (the model's q) and joint torques [mN m]."""
    q = rng.uniform(Q_MIN_RAD, Q_MAX_RAD, size=(n, 3))
    torque_mnm = rng.uniform(-350.0, 350.0, size=(n, 3))
    return q, torque_mnm


def driver_samples(
    q: np.ndarray, torque_mnm: np.ndarray, rng: np.random.Generator, **config: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The driver's measured_js positions and efforts (samples x 6) of raw values."""
    rows = [
        saw_measured_js(qi, rng.uniform(-2, 2, 3), ti, rng.uniform(-40, 40, 3), **config)
        for qi, ti in zip(q, torque_mnm, strict=True)
    ]
    return np.array([r[1] for r in rows]), np.array([r[2] for r in rows])


def test_builtin_driver_is_listed_and_loads() -> None:
    driver = builtin_driver("sensable-phantom")
    assert set(BUILTIN_DRIVERS) == {"sensable-phantom"}
    assert driver.driver_joints == ("waist", "shoulder", "elbow")
    assert driver.base_frame == "base"
    assert driver.rate_hz == 500.0
    assert not driver.publishes_velocity
    assert driver.effort_unit == "mN m"
    # the relative elbow the driver publishes is the model's T applied to q (conventions.md)
    np.testing.assert_array_equal(driver.coupling_p, np.linalg.inv(OMNI_COUPLING))
    with pytest.raises(ModelError, match="unknown driver 'nope'"):
        builtin_driver("nope")


def test_to_model_recovers_raw_openhaptics_values() -> None:
    rng = np.random.default_rng(35)
    driver = builtin_driver("sensable-phantom")
    q, torque_mnm = random_raw(rng, 200)
    for qi, ti in zip(q, torque_mnm, strict=True):
        names, position, effort = saw_measured_js(qi, rng.uniform(-2, 2, 3), ti, np.ones(3))
        q_model, tau_model = driver.to_model(names, position, effort)
        np.testing.assert_allclose(q_model, qi, rtol=0, atol=1e-12)
        assert tau_model is not None
        np.testing.assert_allclose(tau_model, ti * 1e-3, rtol=0, atol=1e-12)


def test_to_driver_is_the_drivers_own_conversion() -> None:
    rng = np.random.default_rng(36)
    driver = builtin_driver("sensable-phantom")
    q, torque_mnm = random_raw(rng, 50)
    positions, efforts = driver_samples(q, torque_mnm, rng)
    names, x, e = driver.to_driver(q, torque_mnm * 1e-3)
    assert names == NAMES[:3]
    np.testing.assert_allclose(x, positions[:, :3], rtol=0, atol=1e-12)
    assert e is not None
    np.testing.assert_allclose(e, efforts[:, :3], rtol=0, atol=1e-9)  # mN m


def test_to_model_takes_samples_and_names_in_any_order() -> None:
    rng = np.random.default_rng(37)
    driver = builtin_driver("sensable-phantom")
    q, torque_mnm = random_raw(rng, 20)
    positions, efforts = driver_samples(q, torque_mnm, rng)
    order = [5, 2, 0, 4, 1, 3]
    q_model, tau_model = driver.to_model(
        [NAMES[i] for i in order], positions[:, order], efforts[:, order]
    )
    np.testing.assert_allclose(q_model, q, rtol=0, atol=1e-12)
    assert tau_model is not None
    np.testing.assert_allclose(tau_model, torque_mnm * 1e-3, rtol=0, atol=1e-12)
    q_only, no_tau = driver.to_model(NAMES, positions, [])
    assert no_tau is None
    np.testing.assert_allclose(q_only, q, rtol=0, atol=1e-12)


def test_the_drivers_joint_scales_and_offsets_are_undone_by_scale_and_offset() -> None:
    rng = np.random.default_rng(38)
    scales = np.array([1.02, 0.97, 1.05, 1.0, 1.0, 1.0])
    offsets = np.array([0.1, -0.2, 0.3, 0.0, 0.0, 0.0])
    builtin = builtin_driver("sensable-phantom")
    driver = dataclasses.replace(
        builtin,
        positions=tuple(
            dataclasses.replace(p, scale=1 / scales[i], offset_rad=-offsets[i] / scales[i])
            for i, p in enumerate(builtin.positions)
        ),
    )
    q, torque_mnm = random_raw(rng, 50)
    positions, _ = driver_samples(q, torque_mnm, rng, joint_scales=scales, joint_offsets=offsets)
    q_model, _ = driver.to_model(NAMES, positions)
    np.testing.assert_allclose(q_model, q, rtol=0, atol=1e-12)
    _, x, _ = driver.to_driver(q_model)
    np.testing.assert_allclose(x, positions[:, :3], rtol=0, atol=1e-12)


def test_builtin_efforts_do_the_same_work_as_the_raw_torques() -> None:
    """OpenHaptics' torques are conjugate to its raw angles, which are the model's q."""
    rng = np.random.default_rng(39)
    driver = builtin_driver("sensable-phantom")
    q, torque_mnm = random_raw(rng, 30)
    qd = rng.normal(size=q.shape)
    positions, efforts = driver_samples(q, torque_mnm, rng)
    _, tau = driver.to_model(NAMES, positions, efforts)
    assert tau is not None
    np.testing.assert_allclose(
        np.sum(tau * qd, axis=1), np.sum(torque_mnm * 1e-3 * qd, axis=1), atol=1e-12
    )
    # ... and the published efforts are NOT conjugate to the published (relative) positions
    conjugate = effort_coupling_conjugate_to_positions(driver)
    assert not np.allclose(conjugate, np.eye(3))


signs = st.sampled_from([-1.0, 1.0])
offsets = st.floats(-3.0, 3.0)
scales = st.floats(0.5, 2.0) | st.floats(-2.0, -0.5)


@st.composite
def interfaces(draw: st.DrawFn) -> DriverInterface:
    n = draw(st.integers(1, 4))
    joints = draw(st.permutations([f"j{i}" for i in range(n)]))
    coupling = np.eye(n) + np.tril(draw(arrays(float, (n, n), elements=st.floats(-1.0, 1.0))), -1)
    return DriverInterface(
        name="random",
        base_frame="base",
        rate_hz=draw(st.floats(1.0, 2000.0)),
        publishes_velocity=draw(st.booleans()),
        positions=tuple(PositionEntry(j, draw(signs), draw(offsets), draw(scales)) for j in joints),
        efforts=tuple(EffortEntry(j, draw(signs)) for j in draw(st.permutations(joints))),
        effort_unit=draw(st.sampled_from(["N m", "mN m"])),
        position_coupling=coupling,
        effort_coupling=coupling.T @ np.diag(draw(arrays(float, n, elements=scales))),
    )


@settings(max_examples=60, deadline=None)
@given(interfaces(), st.integers(0, 2**32 - 1))
def test_round_trips(driver: DriverInterface, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = driver.n_joints
    q = rng.uniform(-2, 2, size=(5, n))
    tau = rng.uniform(-1, 1, size=(5, n))
    names, x, e = driver.to_driver(q, tau)
    q_back, tau_back = driver.to_model(names, x, e)
    assert tau_back is not None
    np.testing.assert_allclose(q_back, q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tau_back, tau, rtol=0, atol=1e-9)
    q2, tau2 = driver.to_model(names, x, e)
    names2, x2, e2 = driver.to_driver(q2, tau2)
    assert names2 == names
    np.testing.assert_allclose(x2, x, rtol=0, atol=1e-9)
    assert e2 is not None
    np.testing.assert_allclose(e2, e, rtol=1e-9, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(interfaces(), st.integers(0, 2**32 - 1))
def test_virtual_work_of_efforts_conjugate_to_the_published_positions(
    driver: DriverInterface, seed: int
) -> None:
    """tau = K^-T e: the power e . xd of the driver equals tau . qd of the model."""
    rng = np.random.default_rng(seed)
    conjugate = dataclasses.replace(
        driver,
        efforts=tuple(EffortEntry(j, 1.0) for j in driver.driver_joints),
        effort_unit="N m",
        effort_coupling=effort_coupling_conjugate_to_positions(driver),
    )
    n = driver.n_joints
    x = rng.normal(size=n)
    xd = rng.normal(size=n)
    e = rng.normal(size=n)
    names = driver.driver_joints
    q, tau = conjugate.to_model(names, x, e)
    q_later, _ = conjugate.to_model(names, x + 1e-6 * xd)
    qd = (q_later - q) / 1e-6  # q is affine in x: exact up to rounding
    assert tau is not None
    assert float(tau @ qd) == pytest.approx(float(e @ xd), rel=1e-6, abs=1e-9)


def cartesian_samples(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """measured_js positions / efforts with the driver's measured_cp and measured_cf."""
    rng = np.random.default_rng(seed)
    q, _ = random_raw(rng, n)
    force_n = rng.uniform(-1.0, 1.0, size=(n, 3))  # HD_LAST_FORCE [N], clamped at 2 N
    torque_mnm = np.array(
        [1e3 * tip_jacobian_formula(qi).T @ fi for qi, fi in zip(q, force_n, strict=True)]
    )
    positions, efforts = driver_samples(q, torque_mnm, rng)
    cp = np.array([tip_position_formula(qi) for qi in q]) + OPENHAPTICS_ORIGIN_M
    return positions, efforts, cp, force_n


def file_with(tmp_path: Path, old: str, new: str) -> Path:
    text = (BUILTIN / "sensable_phantom.toml").read_text()
    assert text.count(old) == 1, old
    path = tmp_path / "driver.toml"
    path.write_text(text.replace(old, new))
    return path


def test_builtin_passes_both_checks() -> None:
    driver = builtin_driver("sensable-phantom")
    positions, efforts, cp, force = cartesian_samples(60, 40)
    result = check_positions(driver, tip_position_formula, NAMES, positions, cp)
    assert result.ok, result.findings
    assert result.residual < 1e-9
    assert result.base_offset_m is not None
    np.testing.assert_allclose(result.base_offset_m, OPENHAPTICS_ORIGIN_M, atol=1e-9)
    effort_result = check_efforts(driver, tip_jacobian_formula, NAMES, positions, efforts, force)
    assert effort_result.ok, effort_result.findings


@pytest.mark.parametrize(
    ("old", "new", "field", "joint"),
    [
        (
            '{ joint = "waist", sign = -1,',
            '{ joint = "waist", sign = 1,',
            "positions[0].sign",
            "waist",
        ),
        (
            '{ joint = "shoulder", sign = 1,',
            '{ joint = "shoulder", sign = -1,',
            "positions[1].sign",
            "shoulder",
        ),
        (
            '{ joint = "elbow", sign = 1, offset_rad = 0.0 }',
            '{ joint = "elbow", sign = 1, offset_rad = 0.3 }',
            "positions[2].offset_rad",
            "elbow",
        ),
        (
            '{ joint = "shoulder", sign = 1, offset_rad = 0.0 }',
            '{ joint = "shoulder", sign = 1, offset_rad = -0.25 }',
            "positions[1].offset_rad",
            "shoulder",
        ),
    ],
)
def test_a_wrong_position_entry_is_named(
    tmp_path: Path, old: str, new: str, field: str, joint: str
) -> None:
    driver = load_driver_interface(file_with(tmp_path, old, new))
    positions, _, cp, _ = cartesian_samples(60, 41)
    result = check_positions(driver, tip_position_formula, NAMES, positions, cp)
    assert not result.ok
    assert len(result.findings) == 1
    assert result.findings[0].startswith(field)
    assert repr(joint) in result.findings[0]


def test_a_wrong_offset_reports_the_right_value(tmp_path: Path) -> None:
    driver = load_driver_interface(
        file_with(tmp_path, "offset_rad = 0.0 },\n]", "offset_rad = 0.3 },\n]")
    )
    positions, _, cp, _ = cartesian_samples(60, 42)
    (finding,) = check_positions(driver, tip_position_formula, NAMES, positions, cp).findings
    assert "by -0.3000 rad" in finding
    assert "offset_rad = 0.0000" in finding


def test_a_wrong_coupling_is_not_blamed_on_one_entry(tmp_path: Path) -> None:
    path = file_with(
        tmp_path, "[[1, 0, 0], [0, 1, 0], [0, 1, 1]]", "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]"
    )
    positions, _, cp, _ = cartesian_samples(60, 43)
    (finding,) = check_positions(
        load_driver_interface(path), tip_position_formula, NAMES, positions, cp
    ).findings
    assert "no single sign or offset" in finding


def test_a_wrong_effort_unit_is_named(tmp_path: Path) -> None:
    driver = load_driver_interface(
        file_with(tmp_path, 'effort_unit = "mN m"', 'effort_unit = "N m"')
    )
    positions, efforts, _, force = cartesian_samples(60, 44)
    result = check_efforts(driver, tip_jacobian_formula, NAMES, positions, efforts, force)
    assert not result.ok
    (finding,) = result.findings
    assert finding.startswith("effort_unit looks wrong")
    assert "'mN m'" in finding


def test_a_flipped_effort_sign_is_named(tmp_path: Path) -> None:
    driver = load_driver_interface(
        file_with(tmp_path, '{ joint = "shoulder", sign = 1 }', '{ joint = "shoulder", sign = -1 }')
    )
    positions, efforts, _, force = cartesian_samples(60, 45)
    (finding,) = check_efforts(
        driver, tip_jacobian_formula, NAMES, positions, efforts, force
    ).findings
    assert finding.startswith("efforts[1].sign")
    assert "'shoulder'" in finding


def test_missing_joint_in_a_joint_state_is_named() -> None:
    driver = builtin_driver("sensable-phantom")
    with pytest.raises(DataError, match="no position joint 'elbow'"):
        driver.to_model(["waist", "shoulder"], [0.0, 0.0])
    with pytest.raises(DataError, match="3 joint names but position has shape"):
        driver.to_model(["waist", "shoulder", "elbow"], [0.0, 0.0])


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        (
            '{ joint = "waist", sign = -1,',
            '{ joint = "waist", sign = 0.5,',
            "driver.positions[0].sign",
        ),
        ('effort_unit = "mN m"', 'effort_unit = "mNm"', "driver.effort_unit"),
        ('effort_unit = "mN m"', "effort_unit = 3", "driver.effort_unit"),
        ("rate_hz = 500.0", "rate_hz = -1.0", "driver.rate_hz"),
        ("rate_hz = 500.0", "", "driver.rate_hz"),
        ('{ joint = "elbow", sign = 1 },\n]', '{ joint = "roll", sign = 1 },\n]', "driver.efforts"),
        (
            '{ joint = "shoulder", sign = 1 },',
            '{ joint = "waist", sign = 1 },',
            "driver.efforts[1].joint",
        ),
        ("[[1, 0, 0], [0, 1, 0], [0, 1, 1]]", "[[1, 0, 0], [0, 1, 0]]", "driver.position_coupling"),
        (
            "[[1, 0, 0], [0, 1, 0], [0, 1, 1]]",
            "[[1, 0, 0], [0, 1, 0], [0, 1]]",
            "driver.position_coupling",
        ),
        (
            "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]",
            "[[1, 0, 0], [0, 1, 0], [0, 0, 0]]",
            "driver.effort_coupling",
        ),
        ("publishes_velocity = false", "publishes_velocity = false\nspeed = 3", "driver.speed"),
    ],
)
def test_bad_driver_files_name_the_file_and_field(
    tmp_path: Path, old: str, new: str, field: str
) -> None:
    path = file_with(tmp_path, old, new)
    with pytest.raises(ModelError) as caught:
        load_driver_interface(path)
    message = str(caught.value)
    assert str(path) in message
    assert re.search(rf"field '{re.escape(field)}'", message), message


def test_a_robot_description_may_carry_a_driver_table(tmp_path: Path) -> None:
    driver_table = (BUILTIN / "sensable_phantom.toml").read_text().split("[driver]", 1)[1]
    robot = tmp_path / "arm.toml"
    robot.write_text(
        'format = "teleop-force-robot"\nversion = 1\nname = "arm"\n'
        "coupling = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]\n"
        "[dh]\nrows = [\n"
        "  { alpha_rad = 1.5707963267948966, a_m = 0.0, d_m = 0.0, mass_kg = 0.1 },\n"
        "  { alpha_rad = 0.0, a_m = 0.135, d_m = 0.0, mass_kg = 0.1 },\n"
        "  { alpha_rad = 0.0, a_m = 0.135, d_m = 0.0, mass_kg = 0.1 },\n]\n"
        "[driver]" + driver_table
    )
    assert load_robot_description(robot).n_joints == 3
    assert load_driver_interface(robot).driver_joints == ("waist", "shoulder", "elbow")
    robot.write_text(robot.read_text().split("[driver]")[0])
    with pytest.raises(ModelError, match=r"field 'driver': missing"):
        load_driver_interface(robot)
