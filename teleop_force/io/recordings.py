"""Read any supported recording into an interchange :class:`Recording`, by file type.

Besides the project's own files (interchange ``.csv``, ``.mcap`` sessions), the native data of
the built-in real robots are read directly: a headerless CSV of 21 numbers per row is a dVRK
MTM trajectory (:func:`teleop_force.io.dvrk_mtm_csv.read_mtm_csv`), a folder of the test stand's
``.dat`` logs is a test-stand recording
(:func:`teleop_force.io.teststand_logs.read_teststand_folder`).
The native formats are recognised by content; ``robot`` (the ``--robot`` of the command, or
the robot a model was identified for) only checks that the data fits the robot.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from teleop_force.errors import DataError
from teleop_force.io.interchange_csv import Recording, read_interchange_csv

if TYPE_CHECKING:
    from teleop_force.robots.driver_interface import DriverInterface


def read_recording(path: Path, n_joints: int | None = None, robot: str | None = None) -> Recording:
    """Read a ``.csv`` interchange file, a ``.mcap`` session or a built-in robot's native data."""
    return read_recording_with_notes(path, n_joints, robot)[0]


def read_recording_with_notes(
    path: Path,
    n_joints: int | None = None,
    robot: str | None = None,
    driver: DriverInterface | None = None,
) -> tuple[Recording, tuple[str, ...]]:
    """Like :func:`read_recording`, plus notes on what reading did (rows dropped...).

    ``driver``: a session's joint states are this driver's, converted with it (a ``.mcap``
    only; without it, a session recorded through a driver names its own description).
    """
    path = Path(path)
    if not path.exists():
        raise DataError("no such file", path=path)
    if driver is not None and path.suffix.lower() != ".mcap":
        raise DataError("a driver description applies to .mcap sessions only", path=path)
    if path.is_dir():
        from teleop_force.io.teststand_logs import is_teststand_folder, read_teststand_folder
        from teleop_force.robots.teststand import NAME

        if not is_teststand_folder(path):
            raise DataError(
                "is a folder, not a recording (nor a folder of test-stand logs)", path=path
            )
        _check_robot(robot, NAME, path, "a folder of test-stand logs")
        log = read_teststand_folder(path)
        return log.recording, (log.note(),)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        from teleop_force.io.dvrk_mtm_csv import looks_like_mtm_csv, read_mtm_csv
        from teleop_force.robots.dvrk_mtm import NAME

        if looks_like_mtm_csv(_first_line(path)):
            _check_robot(robot, NAME, path, "a native dVRK MTM file (no header, 21 columns)")
            trajectory = read_mtm_csv(path)
            return trajectory.recording, (trajectory.note(),)
        return read_interchange_csv(path, n_joints=n_joints), ()
    if suffix == ".mcap":
        from teleop_force.io.mcap_session import read_session_with_notes

        return read_session_with_notes(path, driver=driver)
    raise DataError(
        f"unsupported recording type {suffix!r} (expected .csv, .mcap or a test-stand folder)",
        path=path,
    )


def _first_line(path: Path) -> str:
    try:
        with path.open("rb") as handle:
            return handle.readline(4096).decode("utf-8", "replace")
    except OSError as exc:
        raise DataError(f"cannot read file: {exc.strerror or exc}", path=path) from None


def _check_robot(robot: str | None, expected: str, path: Path, what: str) -> None:
    """Reject native data given to another built-in robot (a description file may fit it)."""
    from teleop_force.robots.file import looks_like_robot_file

    if robot is not None and robot != expected and not looks_like_robot_file(robot):
        raise DataError(f"is {what}: use --robot {expected} (not {robot!r})", path=path)
