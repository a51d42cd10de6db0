"""Zenoh plumbing shared by the service, the master and slave processes, replay and the demo.

Every function wraps ``zenoh.ZError`` in :class:`~teleop_force.errors.TransportError`.

Publishers of data streams use congestion control BLOCK (a slow subscriber slows the
publisher down instead of losing messages). A process that publishes several messages per
tick declares the tick's last one ``express`` and the others not: the earlier ones wait in
Zenoh's batch for the express one, which sends them all in one write, so each link carries
one batch per tick instead of one per message (the receivers wake once; figures:
docs/architecture.md, "One batch per tick"). A message alone on a link is sent at once
either way. Zenoh 1.10 may drop what is published in the first
milliseconds after a subscriber is matched, so a publisher that must not lose anything calls
:func:`wait_for_subscribers` first: it waits for ``matching_status`` and then lets the
routes settle for a moment before the stream starts.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, TransportError
from teleop_force.transport._thread_state import pin_thread_state

#: Time given to a fresh match before the first message that must not be lost.
DEFAULT_SETTLE_S: Final = 0.1


def zenoh_error_text(exc: BaseException) -> str:
    """Zenoh's error message on one line."""
    return " ".join(str(exc).split())


def declare_data_publisher(
    session: zenoh.Session, key: str, *, express: bool = True
) -> zenoh.Publisher:
    """Declare a reliable publisher for a 1 kHz data stream (BLOCK; ``express``: flush at once).

    ``express=False`` for a message that is followed, in the same tick, by an express one of
    the same process (module docstring).
    """
    try:
        return session.declare_publisher(
            key,
            congestion_control=zenoh.CongestionControl.BLOCK,
            express=express,
            priority=zenoh.Priority.REAL_TIME,
        )
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: cannot declare publisher: {zenoh_error_text(exc)}") from None


def declare_subscriber(
    session: zenoh.Session,
    key: str,
    callback: Callable[[zenoh.Sample], Any],
    *,
    direct: bool = False,
) -> zenoh.Subscriber[None]:
    """Declare a callback subscriber.

    ``direct``: run ``callback`` on the Zenoh thread that receives the sample (zenoh-python's
    ``Callback(indirect=False)``) instead of handing it to a Python thread first: no thread
    hop per sample, for short callbacks that must not add latency (the 1 kHz paths). Such a
    callback holds up that Zenoh thread while it runs. The thread keeps one Python thread
    state from its first sample on (:mod:`teleop_force.transport._thread_state`) instead of
    creating and destroying one per sample.
    """
    handler: Any = callback
    if direct:

        def on_sample(sample: zenoh.Sample) -> Any:
            pin_thread_state()
            return callback(sample)

        handler = zenoh.handlers.Callback(on_sample, indirect=False)
    try:
        return session.declare_subscriber(key, handler)
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: cannot declare subscriber: {zenoh_error_text(exc)}") from None


def declare_queue_subscriber(
    session: zenoh.Session, key: str, capacity: int, *, drop_oldest: bool = False
) -> zenoh.Subscriber[zenoh.handlers.Handler[zenoh.Sample]]:
    """Declare a subscriber whose samples wait in a queue, taken with ``try_recv()`` later.

    The queue is zenoh-python's ``FifoChannel(capacity)``, or with ``drop_oldest`` its
    ``RingChannel(capacity)``; a thread of the caller's drains it. No Python code runs per
    sample on Zenoh's receive thread (no interpreter lock taken there): for receivers that
    want the messages but not at once (the session recorder, the demo's supervisor). A full
    FIFO blocks Zenoh's receive thread, so drain it well before ``capacity``; a full ring
    drops its oldest samples.
    """
    if capacity < 1:
        raise ConfigurationError(f"{key}: queue capacity must be >= 1, got {capacity}")
    channel = zenoh.handlers.RingChannel if drop_oldest else zenoh.handlers.FifoChannel
    try:
        return session.declare_subscriber(key, channel(int(capacity)))
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: cannot declare subscriber: {zenoh_error_text(exc)}") from None


def declare_token(session: zenoh.Session, key: str) -> zenoh.LivelinessToken:
    """Declare this process's liveliness token."""
    try:
        return session.liveliness().declare_token(key)
    except zenoh.ZError as exc:
        raise TransportError(
            f"{key}: cannot declare liveliness token: {zenoh_error_text(exc)}"
        ) from None


def declare_liveliness_subscriber(
    session: zenoh.Session, key: str, callback: Callable[[zenoh.Sample], Any]
) -> zenoh.Subscriber[None]:
    """Subscribe to liveliness changes on ``key``, existing tokens reported first (history)."""
    try:
        return session.liveliness().declare_subscriber(key, callback, history=True)
    except zenoh.ZError as exc:
        raise TransportError(
            f"{key}: cannot declare liveliness subscriber: {zenoh_error_text(exc)}"
        ) from None


def declare_json_queryable(
    session: zenoh.Session, key: str, produce: Callable[[], Any]
) -> zenoh.Queryable[None]:
    """Declare a queryable on ``key`` replying ``json.dumps(produce())``."""

    def on_query(query: zenoh.Query) -> None:
        try:
            payload = json.dumps(produce(), allow_nan=False)
        except (TypeError, ValueError) as exc:
            query.reply_err(f"cannot serialise reply: {exc}")
            return
        query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)

    try:
        return session.declare_queryable(key, on_query)
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: cannot declare queryable: {zenoh_error_text(exc)}") from None


def declare_queryable(
    session: zenoh.Session, key: str, callback: Callable[[zenoh.Query], Any]
) -> zenoh.Queryable[None]:
    """Declare a queryable calling ``callback(query)`` (it may reply later, from any thread)."""
    try:
        return session.declare_queryable(key, callback)
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: cannot declare queryable: {zenoh_error_text(exc)}") from None


def reply_json(query: zenoh.Query, key: str, value: Any) -> None:
    """Reply ``json.dumps(value)`` to ``query`` (an error reply if it cannot be serialised)."""
    try:
        try:
            payload = json.dumps(value, allow_nan=False)
        except (TypeError, ValueError) as exc:
            query.reply_err(f"cannot serialise reply: {exc}")
            return
        query.reply(key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
    except zenoh.ZError:  # the querier or the session went away: nobody to tell
        return


def query_json(session: zenoh.Session, key: str, timeout_s: float = 2.0) -> Any:
    """Query ``key`` and return the first reply decoded from JSON.

    Raises:
        TransportError: no reply within ``timeout_s``, an error reply, or a reply that is
            not JSON.

    """
    try:
        replies = session.get(key, timeout=timeout_s)
        for reply in replies:
            if reply.ok is not None:
                text = reply.ok.payload.to_string()
                try:
                    return json.loads(text)
                except ValueError as exc:
                    raise TransportError(f"{key}: reply is not JSON: {exc}") from None
            if reply.err is not None:
                raise TransportError(f"{key}: error reply: {reply.err.payload.to_string()}")
    except zenoh.ZError as exc:
        raise TransportError(f"{key}: query failed: {zenoh_error_text(exc)}") from None
    raise TransportError(f"{key}: no reply within {timeout_s:g} s")


def wait_for_subscribers(
    publisher: zenoh.Publisher,
    timeout_s: float,
    *,
    settle_s: float = DEFAULT_SETTLE_S,
    stop: Callable[[], bool] | None = None,
    ready: Callable[[], bool] | None = None,
) -> bool:
    """Wait until ``publisher`` has a matching subscriber (and ``ready()``), then ``settle_s``.

    ``ready`` names a particular peer when any subscriber would not do (e.g. "the slave's
    liveliness token is present": it declares its subscriber before its token). Returns
    whether both held within ``timeout_s`` (``stop()`` returning True also ends the wait,
    with False).
    """
    if timeout_s < 0.0 or settle_s < 0.0:
        raise ConfigurationError("timeout_s and settle_s must be >= 0")
    deadline = time.perf_counter() + timeout_s
    while True:
        try:
            matched = publisher.matching_status
        except zenoh.ZError as exc:
            raise TransportError(f"matching status unavailable: {zenoh_error_text(exc)}") from None
        if matched and (ready is None or ready()):
            break
        if time.perf_counter() >= deadline or (stop is not None and stop()):
            return False
        time.sleep(0.005)
    time.sleep(settle_s)
    return True


def put(publisher: zenoh.Publisher, payload: bytes) -> None:
    """Publish ``payload``; raise TransportError on failure."""
    try:
        publisher.put(payload)
    except zenoh.ZError as exc:
        raise TransportError(f"put failed: {zenoh_error_text(exc)}") from None


def undeclare_all(*entities: Any) -> None:
    """Undeclare publishers, subscribers, queryables and tokens, ignoring ones already gone."""
    for entity in entities:
        if entity is None:
            continue
        try:
            entity.undeclare()
        except zenoh.ZError:
            continue


def close_session(session: zenoh.Session | None) -> None:
    """Close a session, ignoring a session already closed."""
    if session is None:
        return
    try:
        session.close()
    except zenoh.ZError:
        return
