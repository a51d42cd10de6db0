import numpy as np
from web_ros2 import attachment

from teleop_force.transport import messages as m
from web.plots import plot_frames, uplot_safe
from web.telemetry import Telemetry


def test_uplot_safe_never_starts_with_nan():
    np.testing.assert_array_equal(
        uplot_safe(np.array([np.nan, np.nan, 2.0, np.nan, 3.0]))[:3], [2.0, 2.0, 2.0]
    )
    assert np.isnan(uplot_safe(np.array([1.0, np.nan, 3.0]))[1])  # interior gaps kept
    np.testing.assert_array_equal(uplot_safe(np.full(4, np.nan)), np.zeros(4))


def test_plot_frames_bin_every_stream_on_one_axis():
    tel = Telemetry(capacity=20_000)
    assert plot_frames(tel, 10.0, 300) is None
    t0 = 1_700_000_000_000_000_000
    for k in range(3000):  # 3 s at 1 kHz
        t_ns = t0 + k * 1_000_000
        f = (0.0, -1.0, 0.0) if k % 500 else (np.nan,) * 3
        tel.on_estimate(
            m.ForceEstimateMessage(
                k, t_ns, k, f, (0.1, 0.2, 0.3), (True,) * 3, (1.0,) * 3, (0.5,) * 3, (0.4,) * 3
            ),
            attachment(k + 1, t_ns),
        )
        if k >= 1000:
            tel.on_contact(m.ContactForce(k, t_ns, (0.0, -1.1, 0.0)), attachment(k + 1, t_ns))
    frames = plot_frames(tel, 10.0, 300)
    # Only bins from the first sample on are sent (about 3 s of the 10 s window).
    assert 85 <= frames.x.size <= 92 and frames.x[-1] <= 0 and frames.x[0] >= -3.1
    for arr in (
        frames.force_est,
        frames.force_true,
        frames.tau_motor,
        frames.tau_model,
        frames.tau_ext,
    ):
        assert arr.shape == (frames.x.size, 3)
    np.testing.assert_allclose(frames.force_est[:, 1], -1.0)  # a NaN sample does not spoil a bin
    assert np.isnan(frames.force_true[0, 1]) and np.isclose(frames.force_true[-1, 1], -1.1)
    np.testing.assert_allclose(frames.tau_ext[-1], [0.1, 0.2, 0.3])
