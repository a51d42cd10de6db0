"""Read any supported recording into an interchange :class:`Recording`, by file type."""

from __future__ import annotations

from pathlib import Path

from teleop_force.errors import DataError
from teleop_force.interchange_csv import Recording, read_interchange_csv


def read_recording(path: Path, n_joints: int | None = None) -> Recording:
    """Read a ``.csv`` interchange file or a ``.mcap`` session."""
    path = Path(path)
    if not path.exists():
        raise DataError("no such file", path=path)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return read_interchange_csv(path, n_joints=n_joints)
    if suffix == ".mcap":
        from teleop_force.mcap_session import read_session_as_recording

        return read_session_as_recording(path)
    raise DataError(f"unsupported recording type {suffix!r} (expected .csv or .mcap)", path=path)
