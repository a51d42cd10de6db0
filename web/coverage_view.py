"""The paper's Fig. 4, live: training coverage vs the current velocity trajectory.

Top: the (qd2, qd3) plane with the trust of the coupled networks' training coverage as a
green heat map, the velocity region ``X_r`` (dashed) and the active wavelet centres (dots for
joint 2, rings for joint 3). Bottom: the same for qd1 on a line. Over both, the last few
seconds of the measured velocities: blue where the estimator reported trained ground, red
where it did not, fading with age; the newest sample is a large dot.

The static part is drawn once per model with matplotlib (Agg) into an RGB array
(:func:`render_background`); each frame then only copies it and rasterises the trajectory
with numpy (:func:`compose_frame`), so a frame costs about a millisecond.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

from web.coverage_data import AxisCoverage, CoverageInfo

FIG_SIZE_IN: Final = (4.6, 5.6)
DPI: Final = 100
#: Velocity limits drawn when the model gives no region [rad/s].
DEFAULT_LIMIT_RAD_S: Final = 3.0
TRAINED_RGB: Final = np.array([26, 115, 232], dtype=float)
UNTRAINED_RGB: Final = np.array([217, 48, 37], dtype=float)
UNKNOWN_RGB: Final = np.array([128, 134, 139], dtype=float)


@dataclass(frozen=True)
class AxesMap:
    """Affine map from data coordinates of one matplotlib axes to image pixels.

    ``col = ax_x * x + bx``, ``row = ay * y + by`` (rows grow downwards); pixels are clipped to
    ``[col_min, col_max] x [row_min, row_max]``, the axes' inner box.
    """

    ax: float
    bx: float
    ay: float
    by: float
    col_min: float
    col_max: float
    row_min: float
    row_max: float

    def to_pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel columns and rows of data points, clamped into the axes box."""
        col = np.clip(self.ax * np.asarray(x, float) + self.bx, self.col_min, self.col_max)
        row = np.clip(self.ay * np.asarray(y, float) + self.by, self.row_min, self.row_max)
        return col, row


@dataclass(frozen=True)
class Background:
    """The static figure of one model and the pixel maps of its two axes."""

    image: np.ndarray
    plane: AxesMap
    line: AxesMap
    model_key: str


def _limits(axis: AxisCoverage | None, d: int) -> tuple[tuple[float, float], ...]:
    if axis is None:
        return ((-DEFAULT_LIMIT_RAD_S, DEFAULT_LIMIT_RAD_S),) * d
    out = []
    for lo, hi in zip(axis.lo, axis.hi, strict=True):
        pad = 0.12 * (hi - lo)
        out.append((lo - pad, hi + pad))
    return tuple(out)


def _axes_map(ax: object, height: int) -> AxesMap:
    import matplotlib.axes

    assert isinstance(ax, matplotlib.axes.Axes)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    p = ax.transData.transform(np.array([[x0, y0], [x1, y1]]))
    ax_ = (p[1, 0] - p[0, 0]) / (x1 - x0)
    ay_ = -(p[1, 1] - p[0, 1]) / (y1 - y0)
    bbox = ax.get_window_extent()
    return AxesMap(
        ax=float(ax_),
        bx=float(p[0, 0] - ax_ * x0),
        ay=float(ay_),
        by=float(height - p[0, 1] - ay_ * y0),
        col_min=float(bbox.x0 + 1),
        col_max=float(bbox.x1 - 2),
        row_min=float(height - bbox.y1 + 1),
        row_max=float(height - bbox.y0 - 2),
    )


def render_background(info: CoverageInfo, model_key: str = "") -> Background:
    """Draw the static part of the figure for ``info`` (matplotlib Agg, no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    fig = Figure(figsize=FIG_SIZE_IN, dpi=DPI)
    canvas = FigureCanvasAgg(fig)
    gs = fig.add_gridspec(2, 1, height_ratios=(4.2, 1.0), hspace=0.45)
    ax = fig.add_subplot(gs[0])
    ax1 = fig.add_subplot(gs[1])
    fig.subplots_adjust(left=0.15, right=0.96, top=0.9, bottom=0.08)

    plane = info.plane
    (xl, yl) = _limits(plane, 2)
    ax.set_xlim(*xl)
    ax.set_ylim(*yl)
    if plane is not None and plane.trust is not None:
        ax.imshow(
            plane.trust.T, origin="lower", cmap="Greens", vmin=0.0, vmax=1.25, alpha=0.9,
            extent=(plane.lo[0], plane.hi[0], plane.lo[1], plane.hi[1]),
            interpolation="nearest", aspect="auto",
        )  # fmt: skip
    if plane is not None:
        ax.add_patch(
            Rectangle(
                (plane.lo[0], plane.lo[1]), plane.hi[0] - plane.lo[0], plane.hi[1] - plane.lo[1],
                fill=False, linestyle="--", linewidth=0.8, edgecolor="#5f6368",
            )
        )  # fmt: skip
        for k, (joint, centres) in enumerate(sorted(plane.centres.items())):
            if centres.size:
                ax.scatter(
                    centres[:, 0], centres[:, 1], s=9 if k == 0 else 22,
                    facecolors="#202124" if k == 0 else "none", edgecolors="#202124",
                    linewidths=0.7, label=f"WN {joint + 1} centres", zorder=3,
                )  # fmt: skip
        if any(c.size for c in plane.centres.values()):
            ax.legend(loc="upper left", fontsize=7, framealpha=0.7)
    ax.set_xlabel("qd2 [rad/s]", fontsize=9)
    ax.set_ylabel("qd3 [rad/s]", fontsize=9)
    ax.set_title("Fig. 4 live: training coverage vs current velocity", fontsize=9.5)
    ax.axhline(0.0, color="#bdc1c6", linewidth=0.5, zorder=0)
    ax.axvline(0.0, color="#bdc1c6", linewidth=0.5, zorder=0)
    ax.tick_params(labelsize=8)

    line = info.line
    (x1l,) = _limits(line, 1)
    ax1.set_xlim(*x1l)
    ax1.set_ylim(0.0, 1.0)
    if line is not None and line.trust is not None:
        ax1.imshow(
            line.trust[None, :], origin="lower", cmap="Greens", vmin=0.0, vmax=1.25, alpha=0.9,
            extent=(line.lo[0], line.hi[0], 0.0, 1.0), interpolation="nearest", aspect="auto",
        )  # fmt: skip
    if line is not None:
        ax1.add_patch(
            Rectangle((line.lo[0], 0.0), line.hi[0] - line.lo[0], 1.0, fill=False,
                      linestyle="--", linewidth=0.8, edgecolor="#5f6368")
        )  # fmt: skip
        for centres in line.centres.values():
            if centres.size:
                ax1.scatter(centres[:, 0], np.full(centres.shape[0], 0.08), s=9,
                            color="#202124", zorder=3)  # fmt: skip
    ax1.set_yticks([])
    ax1.set_xlabel("qd1 [rad/s] (newest at the top)", fontsize=9)
    ax1.tick_params(labelsize=8)
    if info.message:
        fig.text(0.5, 0.995, info.message, ha="center", va="top", fontsize=7.5,
                 color="#5f6368")  # fmt: skip

    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    height = rgba.shape[0]
    return Background(
        image=np.ascontiguousarray(rgba[:, :, :3]),
        plane=_axes_map(ax, height),
        line=_axes_map(ax1, height),
        model_key=model_key,
    )


def _densify(
    col: np.ndarray, row: np.ndarray, step_px: float = 0.8
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample a polyline so neighbours are at most ``step_px`` apart; return source index."""
    if col.size < 2:
        return col, row, np.arange(col.size)
    seg = np.hypot(np.diff(col), np.diff(row))
    s = np.concatenate(([0.0], np.cumsum(seg)))
    if s[-1] <= step_px:
        return col, row, np.arange(col.size)
    s_new = np.arange(0.0, s[-1], step_px)
    index = np.clip(np.searchsorted(s, s_new, side="right") - 1, 0, col.size - 1)
    return np.interp(s_new, s, col), np.interp(s_new, s, row), index


def _stamp(
    image: np.ndarray,
    col: np.ndarray,
    row: np.ndarray,
    rgb: np.ndarray,
    alpha: np.ndarray,
    radius: int,
) -> None:
    """Alpha-blend round dots of ``radius`` at the pixels into uint8 ``image`` (in place)."""
    h, w = image.shape[:2]
    c0 = np.rint(col).astype(np.int64)
    r0 = np.rint(row).astype(np.int64)
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            if dr * dr + dc * dc > radius * radius + radius:
                continue
            rr = np.clip(r0 + dr, 0, h - 1)
            cc = np.clip(c0 + dc, 0, w - 1)
            a = alpha[:, None]
            blended = (1.0 - a) * image[rr, cc] + a * rgb
            image[rr, cc] = np.clip(blended, 0.0, 255.0).astype(np.uint8)


def compose_frame(
    background: Background,
    qd: np.ndarray,
    trained: np.ndarray,
    age_fraction: np.ndarray,
    *,
    known: np.ndarray | None = None,
    trained_line: np.ndarray | None = None,
) -> np.ndarray:
    """Return the background with the trajectory drawn over it (uint8 RGB).

    Args:
        background: From :func:`render_background`.
        qd: Velocities (N, 3), oldest first.
        trained: Whether joints 2 and 3 were on trained ground at each sample (N,).
        age_fraction: 0 for the newest sample, 1 for the oldest (N,); older samples fade.
        known: Whether the trained flag is known at each sample (N,); unknown is grey.
        trained_line: Whether joint 1 was on trained ground (N,) (default ``trained``).

    """
    qd = np.asarray(qd, dtype=float)
    n = qd.shape[0]
    trained = np.asarray(trained, dtype=bool)
    known_a = np.ones(n, dtype=bool) if known is None else np.asarray(known, dtype=bool)
    line_flags = trained if trained_line is None else np.asarray(trained_line, dtype=bool)
    keep = np.all(np.isfinite(qd), axis=1)
    qd, age = qd[keep], np.asarray(age_fraction, dtype=float)[keep]
    if qd.shape[0] == 0:
        return background.image.copy()
    image = background.image.copy()
    alpha = np.clip(1.0 - 0.75 * age, 0.2, 1.0)
    colour = _colours(trained[keep], known_a[keep])
    colour_line = _colours(line_flags[keep], known_a[keep])

    col, row = background.plane.to_pixels(qd[:, 1], qd[:, 2])
    dc, dr, idx = _densify(col, row)
    _stamp(image, dc, dr, colour[idx], alpha[idx], radius=1)

    line = background.line
    col1, _ = line.to_pixels(qd[:, 0], np.zeros(qd.shape[0]))
    row1 = line.row_min + 2 + (line.row_max - line.row_min - 4) * age
    dc1, dr1, idx1 = _densify(col1, row1)
    _stamp(image, dc1, dr1, colour_line[idx1], alpha[idx1], radius=1)

    _stamp(image, col[-1:], row[-1:], colour[-1:], np.ones(1), radius=5)
    _stamp(image, col1[-1:], row1[-1:], colour_line[-1:], np.ones(1), radius=4)
    return image


def _colours(trained: np.ndarray, known: np.ndarray) -> np.ndarray:
    colour = np.where(trained[:, None], TRAINED_RGB, UNTRAINED_RGB)
    return np.where(known[:, None], colour, UNKNOWN_RGB)


__all__ = ["AxesMap", "Background", "compose_frame", "render_background"]
