"""Native dVRK MTM data files (``mtm_traj_*_results.csv``): read into an interchange recording.

The files have no header and 21 columns at 200 Hz: the seven joint angles [rad], velocities
[rad/s] and torques [N m] in the dataset's ("file") motor coordinates; the robot itself is
:mod:`teleop_force.robots.dvrk_mtm`.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from teleop_force.errors import DataError
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.dvrk_mtm import N_JOINTS, NATIVE_COLUMNS, SAMPLE_RATE_HZ


@dataclass(frozen=True, eq=False)
class MtmTrajectory:
    """A native MTM file: its distinct rows and the recording the project fits.

    Attributes:
        recording: The samples on the uniform 200 Hz grid ``t = row / 200`` from the first to
            the last distinct row, file coordinates: angles and torques of the distinct rows,
            linear in time across the dropped ones; the angles' motion above
            ``velocity_crossover_hz`` from the logged velocities, and the angles low-passed
            without phase shift at ``smoothing_hz`` (see :func:`read_mtm_csv`).
        kept_rows: 0-based row numbers of the distinct rows.
        q_file_rad, qd_file_rad_s, tau_file_nm: The file's columns at those rows.
        total_rows: Rows in the file.
        repeated_rows: Rows dropped because their joint state (angles and velocities)
            repeated the previous row's (asynchronous logging).
        smoothing_hz: Cut-off of the angle smoothing (``None``: none).
        velocity_crossover_hz: Above it the angles' motion is the logged velocities'
            (``None``: the angles alone).

    """

    recording: Recording
    kept_rows: np.ndarray
    q_file_rad: np.ndarray
    qd_file_rad_s: np.ndarray
    tau_file_nm: np.ndarray
    total_rows: int
    repeated_rows: int
    smoothing_hz: float | None
    velocity_crossover_hz: float | None = None

    def __post_init__(self) -> None:
        n = self.kept_rows.size
        for name in ("q_file_rad", "qd_file_rad_s", "tau_file_nm"):
            if getattr(self, name).shape != (n, N_JOINTS):
                raise DataError(f"{name} must be ({n}, {N_JOINTS})", path=self.recording.source)
        if self.repeated_rows != self.total_rows - n:
            raise DataError("kept and repeated rows do not add up", path=self.recording.source)

    def note(self) -> str:
        """One line telling what was dropped and how the angles were conditioned."""
        smoothing = (
            f"; angles smoothed at {self.smoothing_hz:g} Hz without phase shift"
            if self.smoothing_hz
            else ""
        )
        if self.velocity_crossover_hz:
            smoothing += (
                f"; motion above {self.velocity_crossover_hz:g} Hz from the logged velocities"
            )
        return (
            f"{self.recording.source}: dropped {self.repeated_rows} of {self.total_rows} rows "
            f"({self.repeated_rows / self.total_rows:.1%}) repeating the previous joint state; "
            f"{self.recording.n_samples} samples on the 200 Hz grid{smoothing}"
        )


def looks_like_mtm_csv(first_line: str) -> bool:
    """Whether a CSV's first line is a headerless row of 21 numbers (a native MTM file)."""
    cells = first_line.strip().split(",")
    if len(cells) != NATIVE_COLUMNS:
        return False
    return all(_is_float(c) for c in cells)


#: Default zero-phase smoothing of the angles [Hz] (the excitation is below 1 Hz).
DEFAULT_SMOOTHING_HZ = 6.0
#: Default crossover [Hz] above which the angles' motion comes from the logged velocities.
DEFAULT_VELOCITY_CROSSOVER_HZ = 3.0
_SMOOTHING_ORDER = 4


def read_mtm_csv(
    path: str | os.PathLike[str],
    smoothing_hz: float | None = DEFAULT_SMOOTHING_HZ,
    velocity_crossover_hz: float | None = DEFAULT_VELOCITY_CROSSOVER_HZ,
) -> MtmTrajectory:
    """Read a native ``mtm_traj_*_results.csv`` (no header, 21 columns, 200 Hz).

    Rows whose angles and velocities equal the previous row's are stale samples of the
    asynchronous logger and are dropped. The logger also read the angles at jittered
    instants (consecutive differences scatter far more than the logged velocity allows),
    which the project's momentum-form regressor would differentiate into noise, and the
    project's first-order filters assume steady sampling. So the distinct rows are put back
    on the uniform 200 Hz grid (linear in time across the dropped rows). Above
    ``velocity_crossover_hz`` the angles' motion is taken from the logged velocities instead
    (a zero-phase complementary filter: the angles' low band plus the high band of the
    velocities' integral): the arm's small 3-10 Hz vibrations, which the motor torques carry,
    are in the velocities and lost in the jittered angles. The angles are then low-passed
    forward and backward (4th-order Butterworth, no phase shift, so no bias) at
    ``smoothing_hz``. The torques are left as logged: the project filters them itself.
    """
    path = Path(path)
    for name, value in (
        ("smoothing_hz", smoothing_hz),
        ("velocity_crossover_hz", velocity_crossover_hz),
    ):
        if value is not None and not 0 < value < SAMPLE_RATE_HZ / 2:
            raise DataError(
                f"{name} must be in (0, {SAMPLE_RATE_HZ / 2:g}), got {value}", path=path
            )
    table = _read_table(path)
    state = table[:, : 2 * N_JOINTS]
    repeated = np.zeros(len(table), dtype=bool)
    repeated[1:] = np.all(state[1:] == state[:-1], axis=1)
    kept = np.flatnonzero(~repeated)
    if kept.size < 3:
        raise DataError(f"only {kept.size} distinct rows", path=path)
    t_kept = kept / SAMPLE_RATE_HZ
    grid_rows = np.arange(kept[0], kept[-1] + 1)
    t_grid = grid_rows / SAMPLE_RATE_HZ
    q_grid = _interpolate(t_grid, t_kept, table[kept, :N_JOINTS])
    tau_grid = _interpolate(t_grid, t_kept, table[kept, 2 * N_JOINTS :])
    filtered = smoothing_hz is not None or velocity_crossover_hz is not None
    if filtered and t_grid.size <= 3 * (2 * _SMOOTHING_ORDER + 1):
        raise DataError(f"only {t_grid.size} samples: too short to smooth", path=path)
    if velocity_crossover_hz is not None:
        qd_grid = _interpolate(t_grid, t_kept, table[kept, N_JOINTS : 2 * N_JOINTS])
        integral = np.zeros_like(qd_grid)
        integral[1:] = np.cumsum(0.5 * (qd_grid[1:] + qd_grid[:-1]), axis=0) / SAMPLE_RATE_HZ
        low = _zero_phase(velocity_crossover_hz)
        q_grid = low(q_grid) + integral - low(integral)
    if smoothing_hz is not None:
        q_grid = _zero_phase(smoothing_hz)(q_grid)
    recording = Recording(t_s=t_grid, q_rad=q_grid, tau_nm=tau_grid, source=path)
    return MtmTrajectory(
        recording,
        kept,
        table[kept, :N_JOINTS],
        table[kept, N_JOINTS : 2 * N_JOINTS],
        table[kept, 2 * N_JOINTS :],
        len(table),
        int(repeated.sum()),
        smoothing_hz,
        velocity_crossover_hz,
    )


def _zero_phase(cutoff_hz: float) -> Callable[[np.ndarray], np.ndarray]:
    """4th-order Butterworth low-pass at ``cutoff_hz`` run forward and backward, per column."""
    from scipy.signal import butter, filtfilt  # lazy: scipy.signal is slow to import

    b, a = butter(_SMOOTHING_ORDER, cutoff_hz / (SAMPLE_RATE_HZ / 2))

    def low(x: np.ndarray) -> np.ndarray:
        # Pad with one second of odd reflection: scipy's default (15 samples) leaves start
        # and end transients that the momentum derivative turns into torque spikes.
        return filtfilt(b, a, x, axis=0, padlen=min(x.shape[0] - 1, int(SAMPLE_RATE_HZ)))

    return low


def _interpolate(t_new: np.ndarray, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t_new, t, x[:, j]) for j in range(x.shape[1])], axis=1)


def _read_table(path: Path) -> np.ndarray:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"cannot read file: {exc}", path=path) from None
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise DataError(
            "empty file: expected rows of 21 numbers (q1..q7, qd1..qd7, tau1..tau7)", path=path
        )
    table = np.empty((len(lines), NATIVE_COLUMNS))
    for i, line in enumerate(lines):
        cells = line.split(",")
        if len(cells) != NATIVE_COLUMNS:
            raise DataError(
                f"{len(cells)} cells, a native MTM row has {NATIVE_COLUMNS}", path=path, row=i + 1
            )
        try:
            table[i] = [float(c) for c in cells]
        except ValueError:
            bad = next(j for j, c in enumerate(cells) if not _is_float(c))
            raise DataError(
                f"not a number: {cells[bad].strip()!r}",
                path=path,
                row=i + 1,
                column=_column_name(bad),
            ) from None
    finite = np.isfinite(table)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise DataError("not finite", path=path, row=int(row) + 1, column=_column_name(int(col)))
    return table


def _is_float(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _column_name(index: int) -> str:
    kind = ("q", "qd", "tau")[index // N_JOINTS]
    return f"{kind}{index % N_JOINTS + 1}"
