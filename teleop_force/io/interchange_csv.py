"""One recording in memory (:class:`Recording`) and its interchange CSV file format.

The file format is the one of docs/interchange_csv.md: a header row, then one row per sample,
comma-separated, SI units::

    t,q1,...,qn,tau1,...,taun[,f_x,f_y,f_z]

Columns may come in any order; any other column is ignored (but every row must have as many
cells as the header). Every problem with a file raises :class:`~teleop_force.errors.DataError`
naming the file, the 1-based row as counted in the file (the header is row 1), the column and
what is wrong.
"""

from __future__ import annotations

import io
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import msgspec
import numpy as np
from numpy.typing import ArrayLike, NDArray

from teleop_force.errors import DataError

FORCE_COLUMNS: Final = ("f_x", "f_y", "f_z")
_JOINT_COLUMN: Final = re.compile(r"(q|tau)([1-9][0-9]*)")
# What numpy's loadtxt accepts as a float64 (Python's float() also takes "1_0" and non-ASCII
# digits, which the fast path rejects, so the error search uses this instead).
_NUMBER: Final = re.compile(
    r"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|nan|inf|infinity)",
    re.IGNORECASE,
)
_ROW_HINT: Final = re.compile(r"at row (\d+)")


def _frozen_array(value: ArrayLike, name: str, source: Path | None) -> NDArray[np.float64]:
    try:
        array = np.array(value, dtype=np.float64, copy=True)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} is not a numeric array: {exc}", path=source) from None
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class Recording:
    """Synchronous samples of one robot: time, joint angles, motor torques, optional force.

    Attributes:
        t_s: Sample times [s], shape (N,), strictly increasing.
        q_rad: Measured joint angles [rad], shape (N, n).
        tau_nm: Commanded motor torques [N m], shape (N, n).
        f_tip_in_base_n: Ground-truth force of the tip on the environment in the base frame
            [N], shape (N, 3), or ``None`` when the recording has none.
        source: File the recording was read from, if any (used in error messages).

    Arrays are copied to read-only float64 arrays; every value must be finite.

    """

    t_s: NDArray[np.float64]
    q_rad: NDArray[np.float64]
    tau_nm: NDArray[np.float64]
    f_tip_in_base_n: NDArray[np.float64] | None = None
    source: Path | None = None

    def __post_init__(self) -> None:
        """Copy the arrays read-only and validate shapes, finiteness and time order."""
        source = None if self.source is None else Path(self.source)
        object.__setattr__(self, "source", source)
        t = _frozen_array(self.t_s, "t_s", source)
        q = _frozen_array(self.q_rad, "q_rad", source)
        tau = _frozen_array(self.tau_nm, "tau_nm", source)
        if t.ndim != 1:
            raise DataError(f"t_s must be 1-D, got shape {t.shape}", path=source)
        n_samples = t.shape[0]
        if n_samples == 0:
            raise DataError("recording has no samples", path=source)
        if q.ndim != 2 or q.shape[0] != n_samples or q.shape[1] < 1:
            raise DataError(f"q_rad must have shape ({n_samples}, n), got {q.shape}", path=source)
        if tau.shape != q.shape:
            raise DataError(f"tau_nm must have shape {q.shape}, got {tau.shape}", path=source)
        arrays = {"t_s": t, "q_rad": q, "tau_nm": tau}
        if self.f_tip_in_base_n is not None:
            f = _frozen_array(self.f_tip_in_base_n, "f_tip_in_base_n", source)
            if f.shape != (n_samples, 3):
                raise DataError(
                    f"f_tip_in_base_n must have shape ({n_samples}, 3), got {f.shape}",
                    path=source,
                )
            arrays["f_tip_in_base_n"] = f
        for name, array in arrays.items():
            bad = np.flatnonzero(~np.isfinite(array).reshape(n_samples, -1).all(axis=1))
            if bad.size:
                raise DataError(f"{name} is not finite at sample {bad[0]} (0-based)", path=source)
            object.__setattr__(self, name, array)
        steps = np.flatnonzero(np.diff(t) <= 0.0)
        if steps.size:
            i = int(steps[0]) + 1
            raise DataError(
                f"t_s is not strictly increasing at sample {i} (0-based): "
                f"{t[i]!r} after {t[i - 1]!r}",
                path=source,
            )

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t_s.shape[0])

    @property
    def n_joints(self) -> int:
        """Number of joints n."""
        return int(self.q_rad.shape[1])

    @property
    def has_force(self) -> bool:
        """Whether the recording carries a ground-truth tip force."""
        return self.f_tip_in_base_n is not None

    def __len__(self) -> int:
        """Return the number of samples."""
        return self.n_samples


def header_columns(n_joints: int, with_force: bool) -> list[str]:
    """Return the interchange header for ``n_joints`` joints, with or without force columns."""
    names = ["t"]
    names += [f"q{j}" for j in range(1, n_joints + 1)]
    names += [f"tau{j}" for j in range(1, n_joints + 1)]
    if with_force:
        names += list(FORCE_COLUMNS)
    return names


# --------------------------------------------------------------------------- reading


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise DataError("is a directory, not a CSV file", path=path) from None
    except OSError as exc:
        raise DataError(f"cannot read file: {exc.strerror or exc}", path=path) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        row = data.count(b"\n", 0, exc.start) + 1
        raise DataError(
            f"not UTF-8 text (byte {data[exc.start]:#04x} at offset {exc.start})",
            path=path,
            row=row,
        ) from None
    return text.removeprefix("\ufeff")


def _column_map(header: list[str], path: Path, n_joints: int | None) -> tuple[list[int], int, bool]:
    """Return the file column index of each used column (t, q.., tau.., [f..]), n, has_force."""
    index: dict[str, int] = {}
    for i, raw in enumerate(header):
        name = raw.strip().lower()
        if not name:
            continue
        if name in index:
            raise DataError(
                f"duplicate column (also column {index[name] + 1})", path=path, row=1, column=name
            )
        index[name] = i
    if n_joints is None:
        numbers = {
            int(m.group(2)) for name in index if (m := _JOINT_COLUMN.fullmatch(name)) is not None
        }
        n_joints = 0
        while n_joints + 1 in numbers:
            n_joints += 1
        n_joints = max(n_joints, 1)  # a file with no joint column reports q1 missing
    elif n_joints < 1:
        raise DataError(f"n_joints must be >= 1, got {n_joints}", path=path)
    wanted = header_columns(n_joints, with_force=False)
    present_force = [c for c in FORCE_COLUMNS if c in index]
    has_force = bool(present_force)
    if has_force:
        wanted += list(FORCE_COLUMNS)
    for name in wanted:
        if name not in index:
            raise DataError(
                f"missing column (header is {','.join(h.strip() for h in header)})",
                path=path,
                row=1,
                column=name,
            )
    return [index[name] for name in wanted], n_joints, has_force


def _locate_bad_cell(
    lines: list[str], columns: list[int], names: list[str], path: Path, reason: str
) -> DataError:
    """Find the first cell of ``lines`` (data rows) that is not a finite number.

    numpy's message (``reason``) names the row, 0- or 1-based depending on the failure, so
    the search starts just before it and only rescans the whole file if that finds nothing.
    """
    hint = _ROW_HINT.search(reason)
    start = max(0, int(hint.group(1)) - 2) if hint else 0
    for first, stop in ((start, len(lines)), (0, start)):
        for i in range(first, stop):
            cells = lines[i].split(",")
            for col, name in zip(columns, names, strict=True):
                cell = cells[col].strip()
                if _NUMBER.fullmatch(cell) is None:
                    problem = "empty cell" if not cell else f"not a number: {cell!r}"
                    return DataError(problem, path=path, row=i + 2, column=name)
    return DataError(f"cannot parse the data rows: {reason}", path=path)


def _check_cell_counts(body: str, n_columns: int, path: Path) -> int:
    """Check every data row has ``n_columns`` cells (vectorised); return the row count."""
    raw = np.frombuffer(body.encode("utf-8"), dtype=np.uint8)
    line_ends = np.append(np.flatnonzero(raw == ord("\n")), raw.size)
    commas_before_end = np.searchsorted(np.flatnonzero(raw == ord(",")), line_ends)
    commas_per_line = np.diff(commas_before_end, prepend=0)
    bad = np.flatnonzero(commas_per_line != n_columns - 1)
    if bad.size:
        i = int(bad[0])
        line = body.split("\n")[i]
        found = int(commas_per_line[i]) + 1
        problem = (
            f"ragged row: {found} cells, the header has {n_columns}"
            if line.strip()
            else "empty row"
        )
        raise DataError(problem, path=path, row=i + 2)
    return int(line_ends.size)


def _parse_fast(body: str, n_columns: int, columns: list[int]) -> NDArray[np.float64] | None:
    """Parse the data rows as JSON arrays of ``n_columns`` floats; ``None`` if that fails.

    Several times faster than the cell count check plus loadtxt, and exact (msgspec rounds
    decimal text correctly). The fixed-length row type also checks every row's cell count.
    Anything else (ragged or empty rows, cells JSON does not accept such as ``nan``, ``+1``,
    ``1.`` or blanks) sends the caller to the slow path, which either parses the file or
    reports the bad row and cell.
    """
    row_type = tuple.__class_getitem__((float,) * n_columns)  # tuple[float, ..., float]
    decoder = msgspec.json.Decoder(list.__class_getitem__(row_type))
    try:
        rows = decoder.decode("[[" + body.replace("\n", "],[") + "]]")
    except (msgspec.DecodeError, ValueError):
        return None
    return np.array(rows, dtype=np.float64)[:, columns]


def _parse_loadtxt(
    body: str, columns: list[int], names: list[str], path: Path
) -> NDArray[np.float64]:
    """Parse the data rows with numpy's loadtxt; raise DataError naming the first bad cell."""
    try:
        return np.loadtxt(
            io.StringIO(body),
            delimiter=",",
            usecols=columns,
            dtype=np.float64,
            comments=None,
            ndmin=2,
        )
    except ValueError as exc:
        lines = body.split("\n")
        raise _locate_bad_cell(lines, columns, names, path, str(exc)) from None


def read_interchange_csv(path: str | os.PathLike[str], n_joints: int | None = None) -> Recording:
    """Read an interchange CSV file; raise DataError naming the file, row and column.

    Args:
        path: The file.
        n_joints: Number of joints to read; by default the largest ``n`` such that the header
            has ``q1..qn`` or ``tau1..taun`` (both must then be complete).

    """
    path = Path(path)
    text = _read_text(path)
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    text = text.rstrip()  # trailing blank lines
    if not text:
        raise DataError("empty file: expected a header row t,q1,...,tau1,...", path=path, row=1)
    header_line, newline, body = text.partition("\n")
    header = header_line.split(",")
    columns, n, has_force = _column_map(header, path, n_joints)
    names = header_columns(n, has_force)
    if not newline:
        raise DataError("no data rows after the header", path=path, row=2)

    table = _parse_fast(body, len(header), columns)
    if table is not None:
        n_rows = table.shape[0]
    else:
        n_rows = _check_cell_counts(body, len(header), path)
        table = _parse_loadtxt(body, columns, names, path)
    if table.shape != (n_rows, len(columns)):  # pragma: no cover - guarded by the cell count
        raise DataError(f"expected {n_rows} data rows, parsed {table.shape[0]}", path=path)

    finite = np.isfinite(table)
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        raise DataError(
            f"not finite: {table[row, col]!r}", path=path, row=int(row) + 2, column=names[col]
        )
    t = table[:, 0]
    steps = np.flatnonzero(np.diff(t) <= 0.0)
    if steps.size:
        j = int(steps[0]) + 1
        raise DataError(
            f"time not strictly increasing: {t[j]!r} after {t[j - 1]!r} (row {j + 1})",
            path=path,
            row=j + 2,
            column="t",
        )
    return Recording(
        t_s=t,
        q_rad=table[:, 1 : 1 + n],
        tau_nm=table[:, 1 + n : 1 + 2 * n],
        f_tip_in_base_n=table[:, 1 + 2 * n : 4 + 2 * n] if has_force else None,
        source=path,
    )


# --------------------------------------------------------------------------- writing


def write_interchange_csv(path: str | os.PathLike[str], recording: Recording) -> None:
    """Write ``recording`` as an interchange CSV (exact float round trip, atomic replace)."""
    path = Path(path)
    columns = [recording.t_s[:, None], recording.q_rad, recording.tau_nm]
    if recording.f_tip_in_base_n is not None:
        columns.append(recording.f_tip_in_base_n)
    table = np.hstack(columns)
    header = ",".join(header_columns(recording.n_joints, recording.has_force))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise DataError(f"cannot write file: {exc.strerror or exc}", path=path) from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as out:
            out.write(header + "\n")
            # repr() of a Python float is the shortest string that reads back exactly.
            out.writelines(",".join(map(repr, row)) + "\n" for row in table.tolist())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise DataError(f"cannot write file: {exc.strerror or exc}", path=path) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
