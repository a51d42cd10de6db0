"""Files the dashboard may offer: models and recordings inside allowed folders only.

The browser only ever picks from lists built here, and every path is validated again (after
resolving symlinks and ``..``) right before it is used, so a crafted GUI message cannot make
the dashboard or the service touch a file outside the allowed folders.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from teleop_force.errors import ConfigurationError

#: The repository (parent of the ``web`` package).
PROJECT_ROOT: Final = Path(__file__).resolve().parents[1]
MODEL_SUFFIXES: Final = (".json",)
#: What ``teleop-force replay`` plays: recorded sessions.
RECORDING_SUFFIXES: Final = (".mcap",)
#: Longest list offered in a dropdown.
MAX_LISTED: Final = 500


class PathNotAllowedError(ConfigurationError):
    """A path is outside the allowed folders, missing, or of the wrong type."""


@dataclass(frozen=True)
class Allowlist:
    """A set of folders and the file suffixes allowed in them."""

    folders: tuple[Path, ...]
    suffixes: tuple[str, ...]

    @classmethod
    def of(cls, folders: Iterable[str | Path], suffixes: Sequence[str]) -> Allowlist:
        """Build from folder paths (resolved now; missing folders are kept but list nothing)."""
        seen: list[Path] = []
        for folder in folders:
            resolved = Path(folder).expanduser().resolve()
            if resolved not in seen:
                seen.append(resolved)
        return cls(tuple(seen), tuple(s.lower() for s in suffixes))

    def contains(self, path: str | Path) -> bool:
        """Whether ``path`` (after resolving) lies inside one of the folders."""
        try:
            resolved = Path(path).expanduser().resolve()
        except (OSError, RuntimeError, ValueError):
            return False
        return any(resolved.is_relative_to(folder) for folder in self.folders)

    def resolve(self, path: str | Path) -> Path:
        """Return the resolved path if it is an existing allowed file, else raise.

        Raises:
            PathNotAllowedError: outside the folders, not a regular file, or wrong suffix.

        """
        text = str(path)
        if not text or "\x00" in text:
            raise PathNotAllowedError("empty or invalid path")
        try:
            resolved = Path(text).expanduser().resolve()
        except (OSError, RuntimeError, ValueError) as exc:
            raise PathNotAllowedError(f"{text}: cannot resolve: {exc}") from None
        if not any(resolved.is_relative_to(folder) for folder in self.folders):
            raise PathNotAllowedError(f"{text}: not inside an allowed folder")
        if resolved.suffix.lower() not in self.suffixes:
            raise PathNotAllowedError(f"{text}: expected one of {', '.join(self.suffixes)}")
        if not resolved.is_file():
            raise PathNotAllowedError(f"{text}: no such file")
        return resolved

    def list_files(self) -> list[Path]:
        """List the allowed files in the folders (recursively), sorted, at most MAX_LISTED."""
        found: list[Path] = []
        for folder in self.folders:
            if not folder.is_dir():
                continue
            for candidate in sorted(folder.rglob("*")):
                if candidate.suffix.lower() not in self.suffixes:
                    continue
                try:
                    resolved = self.resolve(candidate)
                except PathNotAllowedError:
                    continue  # e.g. a symlink pointing outside
                if resolved not in found:
                    found.append(resolved)
                if len(found) >= MAX_LISTED:
                    return found
        return found

    def label(self, path: Path) -> str:
        """Short name of an allowed file for a dropdown (relative to the project if possible)."""
        for base in (PROJECT_ROOT, *self.folders):
            if path.is_relative_to(base):
                return str(path.relative_to(base))
        return str(path)


def model_allowlist(extra_dirs: Iterable[str | Path] = (), root: Path = PROJECT_ROOT) -> Allowlist:
    """Model files: ``recordings/``, ``teleop_force/models/`` and any ``--models-dir``."""
    return Allowlist.of(
        [root / "recordings", root / "teleop_force" / "models", *extra_dirs], MODEL_SUFFIXES
    )


def recording_allowlist(root: Path = PROJECT_ROOT) -> Allowlist:
    """Return the allowlist of recordings that may be replayed: ``recordings/`` only."""
    return Allowlist.of([root / "recordings"], RECORDING_SUFFIXES)


__all__ = [
    "MAX_LISTED",
    "MODEL_SUFFIXES",
    "PROJECT_ROOT",
    "RECORDING_SUFFIXES",
    "Allowlist",
    "PathNotAllowedError",
    "model_allowlist",
    "recording_allowlist",
]
