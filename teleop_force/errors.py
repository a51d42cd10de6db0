"""One exception tree for the whole project, rooted in :class:`TeleopForceError`.

Every subclass also inherits the matching built-in exception, so callers may catch either.
Errors raised by pinocchio, zenoh or file parsing are wrapped in one of these, never leaked raw.
"""

from __future__ import annotations

from pathlib import Path


class TeleopForceError(Exception):
    """Root of every error raised by teleop-force."""


class DataError(TeleopForceError, ValueError):
    """A data file or array is malformed: names the file, row, column and the problem."""

    def __init__(
        self,
        problem: str,
        *,
        path: str | Path | None = None,
        row: int | None = None,
        column: str | None = None,
    ) -> None:
        self.problem = problem
        self.path = None if path is None else str(path)
        self.row = row
        self.column = column
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """Return the error as one line: ``file, row R, column C: problem``."""
        where = []
        if self.path is not None:
            where.append(self.path)
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.column is not None:
            where.append(f"column {self.column!r}")
        prefix = ", ".join(where)
        return f"{prefix}: {self.problem}" if prefix else self.problem


class ModelError(TeleopForceError, ValueError):
    """A robot description or dynamic model is invalid or inconsistent."""


class ModelFileError(DataError):
    """A saved model file cannot be read."""


class MessageError(TeleopForceError, ValueError):
    """A wire message is malformed, truncated or of an unknown version."""

    def __init__(self, problem: str, *, key: str | None = None) -> None:
        self.problem = problem
        self.key = key
        super().__init__(f"{key}: {problem}" if key else problem)


class TransportError(TeleopForceError, ConnectionError):
    """A Zenoh session, publisher or subscriber could not be opened or used."""


class SingularityError(TeleopForceError, ArithmeticError):
    """The tip Jacobian is too close to singular to map joint torques to a tip force."""

    def __init__(self, sigma_min: float, threshold: float) -> None:
        self.sigma_min = sigma_min
        self.threshold = threshold
        super().__init__(
            f"tip Jacobian near singular: smallest singular value {sigma_min:.3g} < {threshold:.3g}"
        )


class ConfigurationError(TeleopForceError, ValueError):
    """A configuration value (CLI flag, option, dataclass field) is out of range."""
