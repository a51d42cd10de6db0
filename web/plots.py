"""Live uPlot charts: forces, motor vs model torque per joint, and the residual.

:func:`plot_frames` turns the telemetry rings into time-binned arrays over the last
``window_s`` seconds (every stream binned on the same axis, a few hundred points);
:class:`LivePlots` owns the viser uPlot handles and pushes those arrays to them. The x axis is
seconds relative to the newest sample (-window .. 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import viser
import viser.uplot

from web.buffers import bin_mean
from web.telemetry import FE_F, FE_TAU_EXT, FE_TAU_MODEL, FE_TAU_MOTOR, N_JOINTS, Telemetry

AXIS_RGB: Final = ("#d93025", "#1e8e3e", "#1a73e8")
PLOT_HEIGHT_PX: Final = 200
#: Leading force-estimate columns the charts use (force, residual, coverage, torques).
FE_PLOTTED: Final = max(FE_F.stop, FE_TAU_EXT.stop, FE_TAU_MOTOR.stop, FE_TAU_MODEL.stop)


@dataclass(frozen=True)
class PlotFrames:
    """Binned arrays for every chart, sharing one time axis.

    Attributes:
        t_end_s: Source time of the newest sample (epoch seconds).
        x: Bin centres relative to ``t_end_s`` [s], shape (B,).
        force_est: Estimated tip force (B, 3) [N].
        force_true: Ground-truth tip force (B, 3) [N] (NaN where none).
        tau_motor: Low-passed motor torque (B, n) [N m].
        tau_model: Low-passed model torque (B, n) [N m].
        tau_ext: Residual / external joint torque (B, n) [N m].

    """

    t_end_s: float
    x: np.ndarray
    force_est: np.ndarray
    force_true: np.ndarray
    tau_motor: np.ndarray
    tau_model: np.ndarray
    tau_ext: np.ndarray


def newest_time(telemetry: Telemetry) -> float | None:
    """Source time of the newest sample of the joint-state, estimate and force streams."""
    times = [
        latest[0]
        for latest in (
            telemetry.joint_state.latest(),
            telemetry.estimate.latest(),
            telemetry.contact.latest(),
        )
        if latest is not None
    ]
    return max(times) if times else None


def plot_frames(telemetry: Telemetry, window_s: float, n_bins: int) -> PlotFrames | None:
    """Bin the last ``window_s`` seconds of the rings into ``n_bins`` (``None`` if no data)."""
    t_end = newest_time(telemetry)
    if t_end is None:
        return None
    t_start = t_end - window_s
    end = t_end + 1e-9
    est = telemetry.estimate.window(t_start)
    x, fe = bin_mean(est.t_s, est.values[:, :FE_PLOTTED], t_start, end, n_bins)
    cf = telemetry.contact.window(t_start)
    _, truth = bin_mean(cf.t_s, cf.values, t_start, end, n_bins)
    has_data = np.any(np.isfinite(fe), axis=1) | np.any(np.isfinite(truth), axis=1)
    if not np.any(has_data):
        return None
    first = int(np.argmax(has_data))  # bins before the first sample are not sent
    x, fe, truth = x[first:], fe[first:], truth[first:]
    return PlotFrames(
        t_end_s=t_end,
        x=x - t_end,
        force_est=fe[:, FE_F],
        force_true=truth,
        tau_motor=fe[:, FE_TAU_MOTOR],
        tau_model=fe[:, FE_TAU_MODEL],
        tau_ext=fe[:, FE_TAU_EXT],
    )


def uplot_safe(values: np.ndarray) -> np.ndarray:
    """Make one auto-ranged series safe for uPlot, which cannot take NaN as a gap.

    uPlot starts a series' min/max at its first non-null value, so a leading NaN (NaN is not
    null) poisons the whole chart's range and nothing is drawn. Leading NaNs become the first
    finite value; an all-NaN series becomes zeros. Interior NaNs are kept (uPlot bridges them).
    """
    v = np.array(values, dtype=float, copy=True)
    finite = np.isfinite(v)
    if not np.any(finite):
        return np.zeros_like(v)
    first = int(np.argmax(finite))
    v[:first] = v[first]
    return v


def _series(
    label: str,
    stroke: str,
    *,
    dash: Sequence[float] | None = None,
    width: float = 1.5,
    show: bool = True,
) -> viser.uplot.Series:
    series: dict[str, Any] = {
        "label": label,
        "stroke": stroke,
        "width": width,
        "points": {"show": False},
        "show": show,
    }
    if dash is not None:
        series["dash"] = tuple(dash)
    return series  # type: ignore[return-value]


class LivePlots:
    """The uPlot charts of the dashboard, created in the current GUI container."""

    def __init__(self, gui: viser.GuiApi, window_s: float, n_bins: int) -> None:
        """Create the charts, empty, with a fixed x range of ``[-window_s, 0]``."""
        self.window_s = window_s
        self.n_bins = n_bins
        x = np.linspace(-window_s, 0.0, 2)
        blank = np.full(2, np.nan)
        scales: dict[str, viser.uplot.Scale] = {
            "x": {"time": False, "range": (-window_s, 0.0)},
            "y": {"auto": True},
        }
        axes: tuple[viser.uplot.Axis, ...] = ({"size": 30}, {"size": 56})
        common: dict[str, Any] = {
            "scales": scales, "axes": axes, "height": PLOT_HEIGHT_PX,
            "legend": {"show": True, "live": False},
        }  # fmt: skip
        self._truth_shown = False
        self.force = gui.add_uplot(
            (x, *([blank] * 6)),
            self._force_series(False),
            title="Tip force on the environment [N] (base frame) vs t - now [s]",
            **common,
        )
        self.torque = []
        for j in range(N_JOINTS):
            self.torque.append(
                gui.add_uplot(
                    (x, blank, blank),
                    (
                        _series("t", "#000"),
                        _series(f"motor tau{j + 1}", "#1a73e8"),
                        _series(f"model tau{j + 1}", "#f29900", dash=(5.0, 3.0)),
                    ),
                    title=f"Joint {j + 1}: motor vs model torque [N m] (low-passed)",
                    **common,
                )
            )
        self.residual = gui.add_uplot(
            (x, blank, blank, blank),
            (
                _series("t", "#000"),
                *(_series(f"tau_ext{j + 1}", c) for j, c in enumerate(AXIS_RGB)),
            ),
            title="Residual tau_ext = J^T F [N m]",
            **common,
        )
        self._last_t_end: float | None = None

    def update(self, frames: PlotFrames | None) -> bool:
        """Push new arrays to every chart; return False when there was nothing new."""
        if frames is None or frames.t_end_s == self._last_t_end:
            return False
        self._last_t_end = frames.t_end_s
        x = frames.x
        has_truth = bool(np.any(np.isfinite(frames.force_true)))
        if has_truth != self._truth_shown:  # a hidden series does not take part in the range
            self._truth_shown = has_truth
            self.force.series = self._force_series(has_truth)
        self.force.data = (
            x, *(uplot_safe(frames.force_est[:, k]) for k in range(3)),
            *(uplot_safe(frames.force_true[:, k]) for k in range(3)),
        )  # fmt: skip
        for j, handle in enumerate(self.torque):
            handle.data = (
                x, uplot_safe(frames.tau_motor[:, j]), uplot_safe(frames.tau_model[:, j])
            )  # fmt: skip
        self.residual.data = (x, *(uplot_safe(frames.tau_ext[:, j]) for j in range(N_JOINTS)))
        return True

    @staticmethod
    def _force_series(show_truth: bool) -> tuple[viser.uplot.Series, ...]:
        axis_names = ("x", "y", "z")
        return (
            _series("t", "#000"),
            *(_series(f"est f{a}", c) for a, c in zip(axis_names, AXIS_RGB, strict=True)),
            *(
                _series(f"true f{a}", c, dash=(6.0, 4.0), width=1.0, show=show_truth)
                for a, c in zip(axis_names, AXIS_RGB, strict=True)
            ),
        )


__all__ = ["AXIS_RGB", "LivePlots", "PlotFrames", "newest_time", "plot_frames", "uplot_safe"]
