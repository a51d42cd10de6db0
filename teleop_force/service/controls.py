"""Run-time controls of the force-estimation service: which files a request may touch.

The dashboard (``web/control.py``) asks the running service, with Zenoh gets carrying JSON::

    omni/<d>/service/model     {"load": "/abs/path/model.json"}      load and run that model
    omni/<d>/service/control   {"record": "start", "path": "/abs/recordings/x.mcap"}
    omni/<d>/service/control   {"record": "stop"}

and gets ``{"ok": true, "path": ...}`` or ``{"ok": false, "error": "..."}`` back. Anyone on the
Zenoh network can send these, so the service checks every path itself (the dashboard checked
it too, but the service must not rely on that):

- the path is a string, absolute, at most 4096 characters, without NUL;
- it is resolved (symlinks, ``..``) and must then lie inside an allowed folder: for models
  ``recordings/`` and ``teleop_force/models/`` of the project plus each ``--models-dir``;
  for recordings ``recordings/`` plus each ``--record-dir``;
- a model must be an existing regular ``.json`` file of at most :data:`MAX_MODEL_BYTES`, opened
  without following a symlink swapped in after the check (``O_NOFOLLOW``);
- a recording must be a *new* ``.mcap`` file in an existing allowed folder: an existing file
  (or a symlink with that name) is never overwritten; it is created with ``O_EXCL``.

Every refusal raises :class:`ControlError` with a one-line reason.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from teleop_force.errors import ConfigurationError, ModelFileError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH

#: The project folder (parent of the ``teleop_force`` package).
PROJECT_ROOT: Final = Path(__file__).resolve().parents[2]
#: Largest model file the service loads on request [bytes].
MAX_MODEL_BYTES: Final = 64 * 1024 * 1024
#: Largest JSON request accepted [bytes].
MAX_REQUEST_BYTES: Final = 64 * 1024
MAX_PATH_CHARS: Final = 4096


class ControlError(ConfigurationError):
    """A control request is malformed or refused (the reason is the message)."""


@dataclass(frozen=True)
class AllowedFolders:
    """Folders (resolved) inside which a control request may name a file."""

    folders: tuple[Path, ...]

    @classmethod
    def of(cls, folders: Iterable[str | os.PathLike[str]]) -> AllowedFolders:
        """Resolve and de-duplicate ``folders`` (missing folders allow nothing until created)."""
        seen: list[Path] = []
        for folder in folders:
            resolved = Path(folder).expanduser().resolve()
            if resolved not in seen:
                seen.append(resolved)
        return cls(tuple(seen))

    def _inside(self, resolved: Path) -> bool:
        return any(resolved.is_relative_to(folder) for folder in self.folders)

    def model_file(self, value: object) -> Path:
        """Return the resolved path of an existing allowed ``.json`` file; raise ControlError."""
        text = _path_text(value)
        try:
            resolved = Path(text).resolve(strict=True)
        except (OSError, RuntimeError) as exc:
            raise ControlError(f"{text}: no such file ({_reason(exc)})") from None
        if not self._inside(resolved):
            raise ControlError(f"{text}: not inside an allowed folder ({self.describe()})")
        if resolved.suffix.lower() != ".json":
            raise ControlError(f"{text}: a model file must end in .json")
        if not resolved.is_file():
            raise ControlError(f"{text}: not a regular file")
        return resolved

    def new_recording(self, value: object) -> Path:
        """Return the path of a new allowed ``.mcap`` file (not created yet); raise ControlError."""
        text = _path_text(value)
        given = Path(text)
        if given.name in ("", ".", "..") or given.suffix.lower() != ".mcap":
            raise ControlError(f"{text}: a recording must be a .mcap file name")
        try:
            parent = given.parent.resolve(strict=True)
        except (OSError, RuntimeError) as exc:
            raise ControlError(f"{text}: no such folder ({_reason(exc)})") from None
        if not parent.is_dir():
            raise ControlError(f"{text}: {given.parent} is not a folder")
        if not self._inside(parent):
            raise ControlError(f"{text}: not inside an allowed folder ({self.describe()})")
        target = parent / given.name
        if os.path.lexists(target):
            raise ControlError(f"{text}: exists already (recordings are never overwritten)")
        return target

    def describe(self) -> str:
        """Return the folders as one line, for messages."""
        return ", ".join(str(f) for f in self.folders) or "none"


def model_folders(extra: Iterable[str | os.PathLike[str]] = ()) -> AllowedFolders:
    """Folders models may be loaded from: ``recordings/``, ``teleop_force/models/``, ``extra``."""
    return AllowedFolders.of([PROJECT_ROOT / "recordings", DEFAULT_MODEL_PATH.parent, *extra])


def record_folders(extra: Iterable[str | os.PathLike[str]] = ()) -> AllowedFolders:
    """Folders recordings may be started in: ``recordings/`` and ``extra``."""
    return AllowedFolders.of([PROJECT_ROOT / "recordings", *extra])


def _path_text(value: object) -> str:
    if not isinstance(value, str):
        raise ControlError(f"path must be a string, got {type(value).__name__}")
    if not value or "\x00" in value or len(value) > MAX_PATH_CHARS:
        raise ControlError("path is empty, too long or contains NUL")
    if not Path(value).is_absolute():
        raise ControlError(f"{value}: path must be absolute")
    return value


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return exc.strerror or type(exc).__name__
    return str(exc)


def parse_request(payload: bytes | None) -> dict[str, Any] | None:
    """Decode a request payload: ``None`` if empty, else a JSON object; raise ControlError."""
    if not payload:
        return None
    if len(payload) > MAX_REQUEST_BYTES:
        raise ControlError(f"request of {len(payload)} bytes is too long")
    try:
        data = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ControlError(f"request is not JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ControlError(f"request must be a JSON object, got {type(data).__name__}")
    return data


def read_model_file(path: Path) -> DynamicModel:
    """Read a model file checked by :meth:`AllowedFolders.model_file`; raise ModelFileError."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError as exc:
        raise ModelFileError(f"cannot open: {_reason(exc)}", path=path) from None
    with os.fdopen(fd, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size > MAX_MODEL_BYTES:
            raise ModelFileError(f"{size} bytes is larger than {MAX_MODEL_BYTES}", path=path)
        raw = f.read(MAX_MODEL_BYTES + 1)
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise ModelFileError(f"not JSON: {exc}", path=path) from None
    return DynamicModel.from_dict(data, str(path))


def create_exclusively(path: Path) -> None:
    """Create ``path`` empty, failing if anything (a symlink included) has that name."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
    try:
        os.close(os.open(path, flags, 0o644))
    except OSError as exc:
        raise ControlError(f"{path}: cannot create ({_reason(exc)})") from None


__all__ = [
    "MAX_MODEL_BYTES",
    "MAX_REQUEST_BYTES",
    "PROJECT_ROOT",
    "AllowedFolders",
    "ControlError",
    "create_exclusively",
    "model_folders",
    "parse_request",
    "read_model_file",
    "record_folders",
]
