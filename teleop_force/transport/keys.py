"""The project's own Zenoh keys, in one place: controls, queryables and liveliness.

The live data streams are ROS 2 topics on rmw_zenoh's keys (:mod:`teleop_force.ros2.topics`).
What stays on the project's keys is JSON or a plain payload, per device::

    omni/<device>/service/model      queryable: the model the estimator runs
    omni/<device>/service/stats      queryable: estimator statistics
    omni/<device>/alive/<role>       liveliness token of one process (master, slave, service...)
    omni/<device>/service/adapt      subscriber: payload "on" / "off" switches online adaptation
    omni/<device>/service/control    queryable: JSON requests (start / stop a recording)
    omni/<device>/stats/<role>       queryable: JSON statistics of one process (master, slave...)

The data kinds below (``omni/<device>/measured_js`` ...) name the channels of sessions
recorded before the ROS 2 encoding (see :mod:`teleop_force.io.mcap_session`); nothing is
published on them. Device ids and roles are single key chunks: non-empty, without ``/`` or any
of the Zenoh wildcard / reserved characters ``* $ # ?``, and without surrounding whitespace.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from teleop_force.errors import ConfigurationError

#: First chunk of every key of the project.
ROOT: Final = "omni"

#: Last chunk(s) of the per-device data keys, by topic kind.
MEASURED_JS: Final = "measured_js"
SETPOINT_JS: Final = "setpoint_js"
MEASURED_CF: Final = "measured_cf"
ESTIMATED_CF: Final = "estimated_cf"
STATUS: Final = "status"
SERVICE_MODEL: Final = "service/model"
SERVICE_STATS: Final = "service/stats"
ALIVE: Final = "alive"
SERVICE_ADAPT: Final = "service/adapt"
SERVICE_CONTROL: Final = "service/control"
SERVICE_DIAGNOSTICS: Final = "service/diagnostics"
STATS: Final = "stats"

#: Topic kinds that carry a stream of messages (publisher / subscriber keys).
DATA_KINDS: Final = (MEASURED_JS, SETPOINT_JS, MEASURED_CF, ESTIMATED_CF, STATUS)
#: Kinds of the estimation service's queryables and control subscriber.
SERVICE_KINDS: Final = (
    SERVICE_MODEL, SERVICE_STATS, SERVICE_ADAPT, SERVICE_CONTROL, SERVICE_DIAGNOSTICS,
)  # fmt: skip

_FORBIDDEN_CHARS: Final = frozenset("/*$#?")


def validate_chunk(value: str, what: str = "device id") -> str:
    """Return ``value`` if it is a valid single key chunk, else raise ConfigurationError."""
    if not isinstance(value, str):
        raise ConfigurationError(f"{what} must be a string, got {type(value).__name__}")
    if not value:
        raise ConfigurationError(f"{what} must not be empty")
    if value != value.strip():
        raise ConfigurationError(f"{what} {value!r} has leading or trailing whitespace")
    bad = sorted(_FORBIDDEN_CHARS.intersection(value))
    if bad:
        raise ConfigurationError(
            f"{what} {value!r} contains {' '.join(repr(c) for c in bad)}; "
            "it must not contain any of / * $ # ?"
        )
    return value


def _key(device: str, kind: str) -> str:
    return f"{ROOT}/{validate_chunk(device)}/{kind}"


def measured_js(device: str) -> str:
    """Key of the measured joint state of ``device`` (JointState messages)."""
    return _key(device, MEASURED_JS)


def setpoint_js(device: str) -> str:
    """Key of the joint setpoint sent to ``device`` (JointSetpoint messages)."""
    return _key(device, SETPOINT_JS)


def measured_cf(device: str) -> str:
    """Key of the ground-truth contact force of ``device`` (ContactForce messages)."""
    return _key(device, MEASURED_CF)


def estimated_cf(device: str) -> str:
    """Key of the estimated contact force of ``device`` (ForceEstimate messages)."""
    return _key(device, ESTIMATED_CF)


def status(device: str) -> str:
    """Key of the safety status of ``device`` (Status messages)."""
    return _key(device, STATUS)


def service_model(device: str) -> str:
    """Key of the queryable returning the model the estimator of ``device`` runs."""
    return _key(device, SERVICE_MODEL)


def service_stats(device: str) -> str:
    """Key of the queryable returning the estimator statistics of ``device``."""
    return _key(device, SERVICE_STATS)


def alive(device: str, role: str) -> str:
    """Key of the liveliness token of the process playing ``role`` for ``device``."""
    return f"{_key(device, ALIVE)}/{validate_chunk(role, 'role')}"


def service_adapt(device: str) -> str:
    """Key on which ``"on"`` / ``"off"`` switches the online adaptation of the estimator."""
    return _key(device, SERVICE_ADAPT)


def service_control(device: str) -> str:
    """Key of the queryable taking JSON control requests (recording) for ``device``'s service."""
    return _key(device, SERVICE_CONTROL)


def service_diagnostics(device: str) -> str:
    """Key on which the service publishes its residual watch's diagnostics (JSON, ~1 Hz)."""
    return _key(device, SERVICE_DIAGNOSTICS)


def process_stats(device: str, role: str) -> str:
    """Key of the queryable returning the JSON statistics of the ``role`` process of ``device``."""
    return f"{_key(device, STATS)}/{validate_chunk(role, 'role')}"


def alive_any(device: str | None = None) -> str:
    """Key expression matching every liveliness token (of one device, or of all devices)."""
    if device is None:
        return f"{ROOT}/*/{ALIVE}/*"
    return f"{_key(device, ALIVE)}/*"


def any_device(kind: str) -> str:
    """Key expression matching topic ``kind`` (e.g. ``measured_js``) of every device."""
    if kind not in DATA_KINDS and kind not in (SERVICE_MODEL, SERVICE_STATS):
        raise ConfigurationError(f"unknown topic kind {kind!r}")
    return f"{ROOT}/*/{kind}"


def all_keys() -> str:
    """Key expression matching every key of the project (for a recorder)."""
    return f"{ROOT}/**"


@dataclass(frozen=True)
class ParsedKey:
    """A project key split into its parts; ``role`` is set for liveliness keys only."""

    device: str
    kind: str
    role: str | None = None


def parse(key: str) -> ParsedKey:
    """Split a concrete project key into device, kind and role; raise ConfigurationError."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise ConfigurationError(f"{key!r} is not a teleop-force key ({ROOT}/<device>/<kind>)")
    device = validate_chunk(parts[1])
    rest = "/".join(parts[2:])
    if rest in DATA_KINDS or rest in SERVICE_KINDS:
        return ParsedKey(device=device, kind=rest)
    if len(parts) == 4 and parts[2] == ALIVE:
        return ParsedKey(device=device, kind=ALIVE, role=validate_chunk(parts[3], "role"))
    raise ConfigurationError(f"{key!r}: unknown topic kind {rest!r}")
