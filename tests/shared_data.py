"""Where the shared real-robot datasets live: ``<repo>/../shared/datasets``."""

from __future__ import annotations

from pathlib import Path

import pytest

DATASETS = Path(__file__).resolve().parents[1].parent / "shared" / "datasets"


def require(*parts: str) -> Path:
    """Path under the shared datasets, or skip the test with the reason."""
    path = DATASETS.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared dataset {path} not present (it lives beside the repository, in CI)")
    return path
