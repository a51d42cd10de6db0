"""What every test folder shares: real Zenoh sessions on loopback, Chromium, and the markers.

Markers (select with ``-m``; see tests/README.md):

- ``zenoh``: the test opens a Zenoh session, or starts processes that do (loopback only);
- ``browser``: the test drives Debian's Chromium through playwright; it is skipped, with the
  reason, when /usr/bin/chromium or the playwright package is missing;
- ``slow`` (registered in pyproject.toml, deselected by default): long-running, ``-m slow``.

The Zenoh fixtures open peers with :func:`teleop_force.transport.session.open_session`, with
multicast scouting off and explicit endpoints on 127.0.0.1: tests find only the peers they
name, never each other nor anything else on the network.
"""

from __future__ import annotations

import contextlib
import importlib.util
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)

#: Listen on loopback, on a port the OS picks.
LOOPBACK_ANY_PORT = "tcp/127.0.0.1:0"
#: How long two peers may take to connect on a loaded 2-core machine.
CONNECT_TIMEOUT_S = 20.0
#: Debian's Chromium: the browser tests never use a browser downloaded by playwright.
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = (
    "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
)  # fmt: skip

MARKERS = (
    "zenoh: opens a Zenoh session on loopback, or starts processes that do",
    "browser: drives Debian's Chromium through playwright (skipped when either is missing)",
)


def pytest_configure(config: pytest.Config) -> None:
    for line in MARKERS:
        config.addinivalue_line("markers", line)


#: Fixtures that make a test ``zenoh`` or ``browser`` by themselves (even through another one).
MARKED_BY_FIXTURE = {
    "zenoh_session": "zenoh",
    "zenoh_pair": "zenoh",
    "zenoh_rendezvous": "zenoh",
    "chromium": "browser",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # A test that uses a Zenoh or browser fixture is marked even if its author forgot to.
    for item in items:
        for name in set(getattr(item, "fixturenames", ())) & MARKED_BY_FIXTURE.keys():
            if item.get_closest_marker(MARKED_BY_FIXTURE[name]) is None:
                item.add_marker(MARKED_BY_FIXTURE[name])


def browser_missing() -> str | None:
    """Why the browser tests cannot run here, or None when they can."""
    if not CHROMIUM.exists():
        return f"Debian's chromium is not installed at {CHROMIUM} (apt-get install chromium)"
    if importlib.util.find_spec("playwright") is None:
        return "playwright (python) is not installed"
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    # Before any fixture: a browser test's fixtures start processes for nothing otherwise.
    if item.get_closest_marker("browser") is not None and (reason := browser_missing()):
        pytest.skip(reason)


# --------------------------------------------------------------------------- Zenoh


def loopback_peer(
    *, listen: tuple[str, ...] = (LOOPBACK_ANY_PORT,), connect: tuple[str, ...] = ()
) -> zenoh.Session:
    """A peer session on the given endpoints, multicast scouting off; the caller closes it."""
    return open_session(
        ZenohOptions(mode="peer", listen=listen, connect=connect, multicast_scouting=False)
    )


def wait_connected(listener: zenoh.Session, connector: zenoh.Session) -> None:
    """Wait until ``connector`` sees ``listener`` as a peer (AssertionError after the timeout)."""
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while listener.zid() not in connector.info.peers_zid():
        if time.monotonic() > deadline:
            raise AssertionError(f"peers not connected after {CONNECT_TIMEOUT_S} s")
        time.sleep(0.01)


@dataclass(frozen=True)
class Rendezvous:
    """A peer listening on a fixed loopback endpoint, which other peers and processes join.

    Attributes:
        session: The listening peer (the test's own session).
        endpoint: ``tcp/127.0.0.1:<port>``, the port free when it was chosen.

    """

    session: zenoh.Session
    endpoint: str

    @property
    def process_args(self) -> list[str]:
        """The Zenoh flags that make a ``python -m ...`` process of the project join it."""
        return ["--connect", self.endpoint, "--listen", LOOPBACK_ANY_PORT, "--no-multicast"]

    def connect_peer(self) -> zenoh.Session:
        """Open another peer connected to this one (it listens nowhere); the caller closes it."""
        peer = loopback_peer(listen=(), connect=(self.endpoint,))
        try:
            wait_connected(self.session, peer)
        except BaseException:
            peer.close()
            raise
        return peer


@dataclass(frozen=True)
class ZenohPair:
    """Two connected peers: ``listener`` on ``endpoint`` and ``connector`` joined to it."""

    listener: zenoh.Session
    connector: zenoh.Session
    endpoint: str


@contextlib.contextmanager
def _rendezvous() -> Iterator[Rendezvous]:
    endpoint = listen_endpoint(free_tcp_port())
    session = loopback_peer(listen=(endpoint,))
    try:
        yield Rendezvous(session, endpoint)
    finally:
        session.close()


@pytest.fixture
def zenoh_session() -> Iterator[zenoh.Session]:
    """One peer alone on loopback (any port): for a service and its clients in one session."""
    session = loopback_peer()
    try:
        yield session
    finally:
        session.close()


@pytest.fixture
def zenoh_pair() -> Iterator[ZenohPair]:
    """Two peers connected over loopback TCP, e.g. a service's session and a client's."""
    with _rendezvous() as rendezvous:
        connector = rendezvous.connect_peer()
        try:
            yield ZenohPair(rendezvous.session, connector, rendezvous.endpoint)
        finally:
            connector.close()


@pytest.fixture(scope="module")
def zenoh_rendezvous() -> Iterator[Rendezvous]:
    """A listening peer for the processes a module starts (``rendezvous.process_args``)."""
    with _rendezvous() as rendezvous:
        yield rendezvous


# --------------------------------------------------------------------------- browser


@dataclass(frozen=True)
class ChromiumLaunch:
    """What ``playwright``'s ``chromium.launch`` needs to start Debian's Chromium headless."""

    executable_path: str
    args: tuple[str, ...]


@pytest.fixture(scope="session")
def chromium() -> ChromiumLaunch:
    """Debian's Chromium and its flags; mark the test ``browser`` so it skips without it."""
    if reason := browser_missing():
        pytest.skip(reason)
    return ChromiumLaunch(str(CHROMIUM), CHROMIUM_ARGS)
