"""Online Lyapunov adaptation of a wavelet-network friction inside the running service.

When the service's model has a :class:`~teleop_force.friction.wavelet_network.WaveletNetwork`
friction, :class:`OnlineAdaptation` feeds its :class:`~teleop_force.friction.adaptation.
LyapunovAdapter` one sample at a time with the identifier's signals (see that module)::

    q_v, qd = L_v(q), backward difference of q_v         pre-filtered angles and velocity
    p_L = L(M(q_v) qd)                                   filtered generalized momentum
    u_L = L(L_v(tau))[k - lag] - L(-C^T qd + N + tau_spring + offsets)

computed here exactly as :class:`~teleop_force.estimation.estimator.ForceEstimator` computes its
terms
(same pre-filter ``L_v``, cut-offs, torque lag and rigid-body model). The
adapter updates the network's coefficients in place, so the estimator, which evaluates the
same friction object, uses them from the next sample on. Adaptation assumes the arm moves
*freely*: an external force is indistinguishable from friction and would be learnt as such,
so switch it off during contact (the service only adapts when asked).
"""

from __future__ import annotations

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.adaptation import LyapunovAdapter
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.lowpass import LowPass


def adaptation_unavailable_reason(estimator: ForceEstimator) -> str | None:
    """Why the estimator's model cannot be adapted online (``None``: it can)."""
    friction = estimator.model.friction
    if not isinstance(friction, WaveletNetwork):
        return f"the model's friction is {friction.kind!r}; online adaptation needs 'wn'"
    if estimator.robot is None:
        return "the model has no rigid-body terms (robot 'none'): no momentum to adapt on"
    return None


class OnlineAdaptation:
    """Per-sample driver of a :class:`LyapunovAdapter` on the service's joint-state stream."""

    def __init__(self, estimator: ForceEstimator) -> None:
        """Attach to ``estimator``'s wavelet-network friction; raise ConfigurationError."""
        reason = adaptation_unavailable_reason(estimator)
        if reason is not None:
            raise ConfigurationError(reason)
        robot = estimator.robot
        assert robot is not None  # checked above
        network = estimator.model.friction
        assert isinstance(network, WaveletNetwork)
        self.estimator = estimator
        self.robot = robot
        config = estimator.model.filter_config
        mid = 0.5 * (robot.description.q_min_rad + robot.description.q_max_rad)
        inertia = np.diag(robot.mass_matrix(mid))
        self.adapter = LyapunovAdapter(
            network, cutoff_hz=config.cutoff_hz, inertia_kgm2=tuple(inertia.tolist())
        )
        self._lag = config.torque_lag_samples
        self._angle = LowPass(config.velocity_cutoff_hz)
        self._torque_prefilter = LowPass(config.velocity_cutoff_hz)
        self._momentum = LowPass(config.cutoff_hz)
        self._torque = LowPass(config.cutoff_hz)
        self._rigid = LowPass(config.cutoff_hz)
        self._t_prev: float | None = None
        self._q_prev = np.zeros(estimator.n)
        self.samples = 0
        self.last_error = np.zeros(estimator.n)

    def reset(self) -> None:
        """Forget the signal states (a new stream begins); coefficients are kept."""
        for f in (self._angle, self._torque_prefilter, self._momentum, self._torque, self._rigid):
            f.reset()
        self._t_prev = None
        self.adapter.reset()

    def update(self, t_s: float, q_rad: np.ndarray, tau_nm: np.ndarray) -> None:
        """Feed one sample (same inputs as :meth:`ForceEstimator.update`)."""
        q_raw = np.asarray(q_rad, dtype=float)
        tau = np.asarray(tau_nm, dtype=float)
        dt = 1e-3 if self._t_prev is None else t_s - self._t_prev
        if not dt > 0.0:
            self.reset()
            dt = 1e-3
        first = self._t_prev is None
        q = self._angle.update(q_raw, dt).copy()
        qd = np.zeros_like(q) if first else (q - self._q_prev) / dt
        self._t_prev = t_s
        self._q_prev = q
        robot = self.robot
        p_l = self._momentum.update(robot.momentum(q, qd), dt)
        rigid = (
            robot.coriolis_transpose_gravity(q, qd)
            + robot.spring_torque(q, self.estimator.spring_stiffness)
            + self.estimator.model.offsets_nm
        )
        rigid_l = self._rigid.update(rigid, dt)
        previous = self._torque.state
        previous = None if previous is None else previous.copy()
        tau_now = self._torque.update(self._torque_prefilter.update(tau, dt), dt)
        tau_l = tau_now if (self._lag == 0 or previous is None) else previous
        self.last_error = self.adapter.step(qd, p_l, tau_l - rigid_l, dt)
        self.samples += 1
