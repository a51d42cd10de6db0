"""Fixtures of the live-driver commands' tests: a loopback endpoint and a fake driver on it."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)
from tests.cli.fake_sensable import FakeDriver


@pytest.fixture
def endpoint() -> str:
    return listen_endpoint(free_tcp_port())


@pytest.fixture
def driver(endpoint: str) -> Iterator[FakeDriver]:
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    fake = FakeDriver(session)
    try:
        yield fake
    finally:
        fake.close()
        session.close()
