import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError, TeleopForceError
from teleop_force.robots.device import Device, DeviceClosedError, DeviceReading, TorqueCommand


class _Recorder(Device):
    """The smallest possible device: remembers what it was sent."""

    def __init__(self) -> None:
        super().__init__(torque_limit_nm=[0.5, 0.6])
        self.sent: list[np.ndarray] = []
        self.ticks = 0
        self.closed_count = 0

    @property
    def n_joints(self) -> int:
        return 2

    @property
    def control_period_s(self) -> float:
        return 1e-3

    def read(self) -> DeviceReading:
        self._check_open()
        last = self.sent[-1] if self.sent else np.zeros(2)
        return DeviceReading(t_s=self.ticks * 1e-3, q_rad=np.zeros(2), tau_nm=last)

    def _send_torque(self, tau_nm: np.ndarray) -> None:
        self.sent.append(tau_nm)

    def step(self) -> None:
        self._check_open()
        self.ticks += 1

    def _close(self) -> None:
        self.closed_count += 1


def test_joint_state_is_frozen_and_validated() -> None:
    q = np.array([0.1, 0.2, 0.3])
    state = DeviceReading(
        t_s=1, q_rad=q, tau_nm=np.array([0.0, 0.1, 0.2]), f_tip_in_base_n=np.array([0.0, -1.0, 0.0])
    )
    q[0] = 9.0
    assert state.q_rad[0] == 0.1  # copied
    assert state.n_joints == 3 and isinstance(state.t_s, float)
    with pytest.raises(ValueError):
        state.q_rad[0] = 1.0  # read-only
    assert DeviceReading(0.0, np.zeros(3), np.zeros(3)).f_tip_in_base_n is None
    with pytest.raises(DataError):
        DeviceReading(0.0, np.zeros(3), np.zeros(2))
    with pytest.raises(DataError):
        DeviceReading(0.0, np.zeros(3), np.zeros(3), f_tip_in_base_n=np.zeros(2))
    with pytest.raises(DataError):
        DeviceReading(0.0, np.zeros((3, 1)), np.zeros(3))


def test_command_is_clipped_and_reported() -> None:
    device = _Recorder()
    command = device.command_torque(np.array([0.7, -0.2]))
    assert isinstance(command, TorqueCommand)
    np.testing.assert_allclose(command.tau_nm, [0.5, -0.2])
    np.testing.assert_array_equal(command.clipped, [True, False])
    assert command.any_clipped and device.clip_count == 1
    np.testing.assert_allclose(device.sent[-1], [0.5, -0.2])
    command = device.command_torque(np.array([-0.1, -0.65]))
    np.testing.assert_allclose(command.tau_nm, [-0.1, -0.6])
    assert device.clip_count == 2
    assert not device.command_torque(np.zeros(2)).any_clipped
    assert device.clip_count == 2
    np.testing.assert_allclose(device.torque_limit_nm, [0.5, 0.6])


def test_bad_commands_are_refused_without_sending() -> None:
    device = _Recorder()
    with pytest.raises(DataError):
        device.command_torque(np.zeros(3))
    with pytest.raises(DataError):
        device.command_torque(np.array([np.nan, 0.0]))
    assert device.sent == []


def test_bad_torque_limit() -> None:
    class _Bad(_Recorder):
        def __init__(self) -> None:
            Device.__init__(self, torque_limit_nm=0.0)

    with pytest.raises(ConfigurationError):
        _Bad()


def test_context_manager_closes_once_and_refuses_use() -> None:
    with _Recorder() as device:
        device.command_torque(np.zeros(2))
        device.step()
        assert device.read().t_s == pytest.approx(1e-3)
    assert device.closed and device.closed_count == 1
    device.close()
    assert device.closed_count == 1
    with pytest.raises(DeviceClosedError):
        device.command_torque(np.zeros(2))
    with pytest.raises(TeleopForceError):
        device.step()
