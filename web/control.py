"""Requests from the dashboard to the force-estimation service (:mod:`teleop_force.service`).

Keys and payloads (``<d>`` is the slave's device id):

=============================  =======  ==================================================
key                            how      payload
=============================  =======  ==================================================
``omni/<d>/service/model``     get      none: reply = the model JSON (DynamicModel.to_dict)
``omni/<d>/service/stats``     get      none: reply = the statistics JSON
``omni/<d>/service/adapt``     put      ``on`` / ``off`` (what the service subscribes to)
``omni/<d>/service/model``     get      ``{"load": "/abs/path/model.json"}``
``omni/<d>/service/control``   get      ``{"record": "start", "path": "/abs/recordings/x.mcap"}``
``omni/<d>/service/control``   get      ``{"record": "stop"}``
=============================  =======  ==================================================

The first three are what the service implements today. Loading a model and starting or
stopping a recording at run time are not implemented by the service yet (it loads ``--model``
and records ``--record PATH`` at start): the dashboard sends the last three requests anyway
and then *checks the service's statistics* (``model.path``, ``recording``, ``adaptation``) to
tell the user what actually happened, so nothing is reported as done that was not.

A get reply ``{"ok": false, "error": "..."}`` (or a Zenoh error reply) reports a refusal.
Paths are absolute and were checked to lie inside the allowed folders (:mod:`web.allowlist`);
the service should check them again.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final

import zenoh

from teleop_force.errors import ConfigurationError
from teleop_force.transport import keys
from teleop_force.transport.session import ZenohOptions

#: Last chunks of the control key (not in :mod:`teleop_force.transport.keys` yet).
SERVICE_CONTROL: Final = "service/control"
QUERY_TIMEOUT_S: Final = 2.0
MIN_SPEED: Final = 0.05
MAX_SPEED: Final = 20.0
_NAME_OK: Final = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,100}$")


def control_key(device: str) -> str:
    """Key of the service's control queryable for ``device``."""
    return f"{keys.ROOT}/{keys.validate_chunk(device)}/{SERVICE_CONTROL}"


def load_model_request(device: str, path: Path) -> tuple[str, dict[str, Any]]:
    """Key and payload asking the service of ``device`` to load the model at ``path``.

    The one place that defines the load protocol: change it here to match the service.
    """
    return keys.service_model(device), {"load": str(path)}


def record_request(
    device: str, start: bool, path: Path | None = None
) -> tuple[str, dict[str, Any]]:
    """Key and payload starting (into ``path``) or stopping a recording."""
    if start:
        if path is None:
            raise ConfigurationError("starting a recording needs a path")
        return control_key(device), {"record": "start", "path": str(path)}
    return control_key(device), {"record": "stop"}


def adaptation_request(device: str, enabled: bool) -> tuple[str, str]:
    """Key and payload (``on`` / ``off``, sent with a put) switching online adaptation."""
    return keys.service_adapt(device), "on" if enabled else "off"


def stats_model_path(stats: Any) -> Path | None:
    """Return the model file the service reports running (``stats["model"]["path"]``)."""
    model = stats.get("model") if isinstance(stats, dict) else None
    path = model.get("path") if isinstance(model, dict) else None
    return Path(path).resolve() if isinstance(path, str) and path else None


def stats_adaptation(stats: Any) -> tuple[bool | None, str]:
    """Return ``(enabled, note)`` of the adaptation from the service statistics."""
    block = stats.get("adaptation") if isinstance(stats, dict) else None
    if not isinstance(block, dict) or not isinstance(block.get("enabled"), bool):
        return None, ""
    return block["enabled"], str(block.get("note") or "")


def stats_recording(stats: Any) -> str:
    """Return one line about the service's recording, from its statistics."""
    if not isinstance(stats, dict) or "recording" not in stats:
        return "unknown"
    rec = stats["recording"]
    if not isinstance(rec, dict):
        return "not recording"
    return f"recording {Path(str(rec.get('path', '?'))).name} ({rec.get('messages', '?')} messages)"


def recording_name(text: str, now: float | None = None) -> str:
    """Return a safe file name ``<text>.mcap`` (default ``session-<date>-<time>.mcap``)."""
    name = text.strip() or time.strftime("session-%Y%m%d-%H%M%S", time.localtime(now))
    if name.lower().endswith(".mcap"):
        name = name[:-5]
    if not _NAME_OK.match(name):
        raise ConfigurationError(
            f"recording name {name!r}: use letters, digits, '_', '-', '.' (no folders)"
        )
    return name + ".mcap"


@dataclass(frozen=True)
class ServiceReply:
    """Outcome of one request: ``ok``, a one-line ``text`` for the GUI and the parsed ``data``."""

    ok: bool
    text: str
    data: Any = None


def _parse_reply(reply: zenoh.Reply) -> ServiceReply:
    if reply.ok is not None:
        raw = reply.ok.payload.to_string()
        try:
            data = json.loads(raw) if raw else None
        except json.JSONDecodeError:
            return ServiceReply(True, raw[:200], raw)
        if isinstance(data, dict) and data.get("ok") is False:
            return ServiceReply(False, str(data.get("error", "refused")), data)
        return ServiceReply(True, "ok", data)
    err = reply.err
    text = err.payload.to_string() if err is not None else "error"
    return ServiceReply(False, text[:300])


class ServiceClient:
    """Zenoh requests to the estimation service of one device."""

    def __init__(
        self, session: zenoh.Session, device: str, timeout_s: float = QUERY_TIMEOUT_S
    ) -> None:
        """Bind to ``session`` and ``device``."""
        self._session = session
        self.device = keys.validate_chunk(device)
        self.timeout_s = timeout_s

    def query(
        self, key: str, payload: dict[str, Any] | None = None, timeout_s: float | None = None
    ) -> ServiceReply:
        """Send one query; return the first reply, or a failure if none came in time."""
        kwargs: dict[str, Any] = {"timeout": self.timeout_s if timeout_s is None else timeout_s}
        if payload is not None:
            kwargs["payload"] = json.dumps(payload)
        try:
            replies = self._session.get(key, **kwargs)
            for reply in replies:
                return _parse_reply(reply)
        except zenoh.ZError as exc:
            return ServiceReply(False, f"zenoh error: {exc}")
        return ServiceReply(False, f"no reply on {key} (is the service running?)")

    def request_model_load(self, path: Path) -> ServiceReply:
        """Ask the service to load the model file ``path`` (already validated)."""
        key, payload = load_model_request(self.device, path)
        return self.query(key, payload)

    def fetch_model(self, timeout_s: float | None = None) -> ServiceReply:
        """Fetch the model JSON the service runs."""
        return self.query(keys.service_model(self.device), None, timeout_s)

    def fetch_stats(self, timeout_s: float | None = None) -> ServiceReply:
        """Fetch the service's statistics JSON."""
        return self.query(keys.service_stats(self.device), None, timeout_s)

    def set_recording(self, start: bool, path: Path | None = None) -> ServiceReply:
        """Start (into ``path``) or stop recording."""
        key, payload = record_request(self.device, start, path)
        return self.query(key, payload)

    def set_adaptation(self, enabled: bool) -> ServiceReply:
        """Put ``on`` / ``off`` on the adaptation key (no reply: confirm through the stats)."""
        key, payload = adaptation_request(self.device, enabled)
        try:
            self._session.put(key, payload)
        except zenoh.ZError as exc:
            return ServiceReply(False, f"zenoh error: {exc}")
        return ServiceReply(True, f"sent {payload!r} on {key}")


def zenoh_cli_args(options: ZenohOptions) -> list[str]:
    """Return flags of :func:`~teleop_force.transport.session.add_zenoh_arguments` for ``options``.

    Listening endpoints are not passed on (a child listens on a free loopback port).
    """
    args: list[str] = []
    if options.mode is not None:
        args += ["--mode", options.mode]
    for endpoint in options.connect:
        args += ["--connect", endpoint]
    if options.config_path is not None:
        args += ["--config", str(options.config_path)]
    if options.multicast_scouting is not None:
        args.append("--multicast" if options.multicast_scouting else "--no-multicast")
    return args


def teleop_force_command() -> list[str]:
    """How to run ``teleop-force``: the script next to this interpreter, on PATH, or ``-m``."""
    sibling = Path(sys.executable).with_name("teleop-force")
    if sibling.is_file():
        return [str(sibling)]
    found = shutil.which("teleop-force")
    if found:
        return [found]
    return [sys.executable, "-m", "teleop_force.cli.main"]


def replay_command(
    path: Path, speed: float, zenoh_args: Sequence[str], program: Sequence[str] | None = None
) -> list[str]:
    """Command line of ``teleop-force replay PATH --speed S`` plus the Zenoh flags."""
    if not MIN_SPEED <= speed <= MAX_SPEED:
        raise ConfigurationError(f"replay speed must be in [{MIN_SPEED}, {MAX_SPEED}], got {speed}")
    base = list(program) if program is not None else teleop_force_command()
    return [*base, "replay", str(path), "--speed", f"{speed:g}", *zenoh_args]


class ReplayProcess:
    """At most one ``teleop-force replay`` child at a time, started and stopped from the GUI."""

    def __init__(self) -> None:
        """No child yet."""
        self._proc: subprocess.Popen[bytes] | None = None
        self._log: IO[bytes] | None = None
        self._what = ""
        self._lock = threading.Lock()

    def start(self, command: Sequence[str], what: str) -> str:
        """Start ``command`` (stopping a previous replay first); return a status line."""
        with self._lock:
            self._stop_locked()
            self._log = tempfile.TemporaryFile()  # noqa: SIM115 - kept open while the child runs
            try:
                self._proc = subprocess.Popen(
                    list(command), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                    stderr=self._log, close_fds=True,
                )  # fmt: skip
            except OSError as exc:
                self._log.close()
                self._log = None
                return f"cannot start replay: {exc}"
            self._what = what
            return f"replaying {what} (pid {self._proc.pid})"

    def stop(self) -> str:
        """Stop the running replay, if any; return a status line."""
        with self._lock:
            return self._stop_locked() or "no replay running"

    def _stop_locked(self) -> str:
        proc = self._proc
        if proc is None:
            return ""
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=3.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=3.0)
        self._proc = None
        if self._log is not None:
            self._log.close()
            self._log = None
        return f"replay of {self._what} stopped"

    def status(self) -> str:
        """One line: running, finished (exit code and the last line of its stderr), or idle."""
        with self._lock:
            proc = self._proc
            if proc is None:
                return "idle"
            code = proc.poll()
            if code is None:
                return f"running: {self._what} (pid {proc.pid})"
            tail = ""
            if self._log is not None:
                self._log.seek(0)
                lines = self._log.read().decode("utf-8", "replace").strip().splitlines()
                tail = lines[-1][:200] if lines else ""
            return f"finished: {self._what}, exit {code}" + (f": {tail}" if tail else "")


__all__ = [
    "MAX_SPEED",
    "MIN_SPEED",
    "QUERY_TIMEOUT_S",
    "SERVICE_CONTROL",
    "ReplayProcess",
    "ServiceClient",
    "ServiceReply",
    "adaptation_request",
    "control_key",
    "load_model_request",
    "record_request",
    "recording_name",
    "replay_command",
    "stats_adaptation",
    "stats_model_path",
    "stats_recording",
    "teleop_force_command",
    "zenoh_cli_args",
]
