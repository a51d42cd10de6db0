"""The first-order low-pass filter ``omega / (s + omega)`` of the paper, discretised exactly.

Discrete form (zero-order hold on the input, exact for any sample interval ``dt``)::

    a = exp(-omega * dt)
    y[k] = a * y[k-1] + (1 - a) * x[k]

The streaming :class:`LowPass` keeps its state explicitly (like scipy's ``zi``) and starts at
the first sample (``y[0] = x[0]``); :func:`lowpass_batch` runs the same recursion over a whole
array and gives the same numbers.
"""

from __future__ import annotations

import math

import numpy as np

from teleop_force.errors import ConfigurationError, DataError

DEFAULT_CUTOFF_HZ = 8.0


def smoothing_factor(cutoff_hz: float, dt_s: float) -> float:
    """Return ``a = exp(-2 pi cutoff_hz dt_s)``, the pole of the discrete filter."""
    if cutoff_hz <= 0.0:
        raise ConfigurationError(f"cutoff_hz must be > 0, got {cutoff_hz}")
    if not dt_s > 0.0:
        raise DataError(f"sample interval must be > 0, got {dt_s}")
    return math.exp(-2.0 * math.pi * cutoff_hz * dt_s)


class LowPass:
    """Streaming first-order low-pass filter over a vector signal, with explicit state."""

    def __init__(self, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> None:
        """Create a filter; its state starts empty and takes the first sample's value."""
        smoothing_factor(cutoff_hz, 1.0)
        self.cutoff_hz = cutoff_hz
        self.state: np.ndarray | None = None

    def reset(self, state: np.ndarray | None = None) -> None:
        """Forget the state (or set it to ``state``)."""
        self.state = None if state is None else np.array(state, dtype=float)

    def update(self, x: np.ndarray, dt_s: float) -> np.ndarray:
        """Filter one sample taken ``dt_s`` after the previous one; return the new output."""
        if self.state is None:
            self.state = np.array(x, dtype=float)
            return self.state
        a = smoothing_factor(self.cutoff_hz, dt_s)
        self.state = a * self.state + (1.0 - a) * x
        return self.state


def sample_intervals(t_s: np.ndarray) -> np.ndarray:
    """Return ``dt[k] = t[k] - t[k-1]`` with ``dt[0]`` set to the median interval."""
    t_s = np.asarray(t_s, dtype=float)
    if t_s.ndim != 1 or t_s.size < 2:
        raise DataError("need at least two samples")
    dt = np.diff(t_s)
    if np.any(~(dt > 0)):
        k = int(np.argmax(~(dt > 0))) + 1
        raise DataError(f"time does not increase at sample {k}", row=k)
    return np.concatenate(([float(np.median(dt))], dt))


def _is_uniform(dt: np.ndarray) -> bool:
    return bool(np.ptp(dt) <= 1e-9 * float(np.median(dt)))


def regularised_intervals(t_s: np.ndarray) -> np.ndarray:
    """Return :func:`sample_intervals`, with jitter below 1e-9 relative snapped to the median.

    Time stamps like ``arange(N) / 1000`` differ from a uniform grid by rounding only; one
    exact interval makes per-block filter constants identical (and cacheable), as
    :func:`lowpass_batch` does.
    """
    dt = sample_intervals(t_s)
    if _is_uniform(dt):
        return np.full_like(dt, float(np.median(dt)))
    return dt


def lowpass_batch(
    x: np.ndarray, t_s: np.ndarray, cutoff_hz: float = DEFAULT_CUTOFF_HZ
) -> np.ndarray:
    """Filter ``x`` (time along axis 0) exactly as :class:`LowPass` would, sample by sample."""
    x = np.asarray(x, dtype=float)
    dt = sample_intervals(t_s)
    if x.shape[0] != dt.shape[0]:
        raise DataError(f"signal has {x.shape[0]} samples, time has {dt.shape[0]}")
    if _is_uniform(dt):
        from scipy.signal import lfilter  # lazy: scipy.signal costs ~0.4 s to import

        a = smoothing_factor(cutoff_hz, float(dt[1]))
        zi = a * x[0:1]
        y, _ = lfilter([1.0 - a], [1.0, -a], x, axis=0, zi=zi)
        return y
    a_k = np.exp(-2.0 * math.pi * cutoff_hz * dt)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.shape[0]):
        y[k] = a_k[k] * y[k - 1] + (1.0 - a_k[k]) * x[k]
    return y


def filtered_derivative_batch(
    p: np.ndarray, t_s: np.ndarray, cutoff_hz: float = DEFAULT_CUTOFF_HZ
) -> np.ndarray:
    """Low-pass filtered time derivative of ``p`` without differentiating it.

    The discrete counterpart of ``omega (p - filter(p))``: the filter applied to the backward
    difference ``(p[k] - p[k-1]) / dt``, computed as ``(p_L[k] - p_L[k-1]) / dt``. It is 0 at
    the first sample.
    """
    p_lowpassed = lowpass_batch(p, t_s, cutoff_hz)
    dt = sample_intervals(t_s)
    out = np.zeros_like(p_lowpassed)
    shape = (-1,) + (1,) * (p_lowpassed.ndim - 1)
    out[1:] = np.diff(p_lowpassed, axis=0) / dt[1:].reshape(shape)
    return out


class FilteredDerivative:
    """Streaming form of :func:`filtered_derivative_batch`."""

    def __init__(self, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> None:
        """Create the filter with empty state."""
        self._lowpass = LowPass(cutoff_hz)

    def reset(self) -> None:
        """Forget the state."""
        self._lowpass.reset()

    def update(self, p: np.ndarray, dt_s: float) -> np.ndarray:
        """Feed one sample of ``p``; return the filtered derivative at that sample."""
        previous = self._lowpass.state
        if previous is None:
            self._lowpass.update(p, dt_s)
            return np.zeros_like(np.asarray(p, dtype=float))
        previous = previous.copy()
        current = self._lowpass.update(p, dt_s)
        return (current - previous) / dt_s
