"""Record a session in a background thread, so recording never slows a Zenoh receive thread.

A subscriber callback runs on a Zenoh receive thread; while it runs, that link delivers
nothing else, and with congestion control BLOCK a slow callback ends up blocking the
*publisher* (the master's setpoints, the slave's joint states). So callbacks only hand the raw
wire payload to :meth:`BackgroundRecorder.submit` (a deque append) and one thread records.

The thread wakes every ``batch_interval_s`` (0.1 s, at most a quarter of the writer's flush
interval) and records everything queued in one call, :meth:`SessionWriter.write_payloads
<teleop_force.io.mcap_session.SessionWriter.write_payloads>`: the payloads of each key are
checked and converted to CDR as one numpy block, so the cost per message is a few array
columns, not a decode, an object and an encoder call. Message objects are accepted too
(encoded to their wire bytes first). A malformed payload (or one of another class than its
key's first message) is dropped and reported to ``on_malformed(key, error)``. After each
wake-up the thread closes the writer's chunks once they are ``flush_interval_s -
batch_interval_s`` old (also when idle), so a message is in a complete chunk handed to the OS
at most ``flush_interval_s`` after it was submitted: a killed process loses at most that.

If the writer cannot keep up for long (``max_backlog`` messages waiting), further messages are
dropped from the *recording* and counted; the live data path is never affected.
"""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, Final

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.transport import messages as m

#: Queued messages at most: 60 s of a 6-channel 1 kHz session.
DEFAULT_MAX_BACKLOG: Final = 360_000
#: How often the thread records what was queued [s] (at most a quarter of the flush interval):
#: 500 messages a batch at 5 kHz, where converting a key's messages as one block pays.
DEFAULT_BATCH_INTERVAL_S: Final = 0.1
#: Messages recorded in one call at most.
MAX_BATCH: Final = 20_000
_MESSAGE_CLASSES: Final = tuple(m.MESSAGE_CLASSES.values())


class BackgroundRecorder:
    """Thread writing ``(key, payload or message, log time)`` to a :class:`SessionWriter`.

    Args:
        writer: The session to record into (closed by :meth:`close`).
        on_malformed: Called as ``on_malformed(key, error)`` (from the recording thread) for
            each dropped payload: malformed, of another class than its key's, or not written
            because the file could not be.
        max_backlog: Messages waiting at most; more are dropped (counted in ``dropped``).
        batch_interval_s: The thread records what was queued this often.

    """

    def __init__(
        self,
        writer: SessionWriter,
        on_malformed: Callable[[str, Exception], None] | None = None,
        max_backlog: int = DEFAULT_MAX_BACKLOG,
        *,
        batch_interval_s: float = DEFAULT_BATCH_INTERVAL_S,
    ) -> None:
        """Start the recording thread."""
        if max_backlog < 1:
            raise ConfigurationError(f"max_backlog must be >= 1, got {max_backlog}")
        if not batch_interval_s > 0.0:
            raise ConfigurationError(f"batch_interval_s must be > 0, got {batch_interval_s}")
        self.writer = writer
        self.max_backlog = int(max_backlog)
        #: Messages dropped because the backlog was full.
        self.dropped = 0
        #: Messages recorded.
        self.written = 0
        #: Messages rejected (reported to ``on_malformed``).
        self.malformed = 0
        self._interval_s = min(float(batch_interval_s), writer.flush_interval_s / 4.0)
        self._on_malformed = on_malformed
        self._queue: deque[tuple[str, Any, int]] = deque()
        self._in_flight = 0
        self._stop = threading.Event()
        self._closed = False
        self._finished = False
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    @property
    def backlog(self) -> int:
        """Messages waiting to be written (queued, or in the batch being written)."""
        return len(self._queue) + self._in_flight

    def submit(self, key: str, item: bytes | m.Message, log_time_ns: int) -> None:
        """Queue one wire payload (or message object) received on ``key`` at ``log_time_ns``."""
        if self._closed:
            return
        if len(self._queue) + self._in_flight >= self.max_backlog:
            self.dropped += 1
            return
        self._queue.append((key, item, log_time_ns))

    def _run(self) -> None:
        while True:
            stopping = self._stop.wait(self._interval_s)
            while self._queue and not self._finished:
                self._record_batch()
            if stopping or self._finished:
                return
            with contextlib.suppress(DataError):  # reported with the next batch written
                # Flushing one interval early keeps every message's stay in an open chunk
                # (queued, then written) within the writer's flush interval.
                self.writer.flush_if_due(margin_s=self._interval_s)

    def _record_batch(self) -> None:
        queue = self._queue
        count = min(len(queue), MAX_BATCH)
        self._in_flight = count
        batch = [queue.popleft() for _ in range(count)]
        keys = [entry[0] for entry in batch]
        payloads = [entry[1] for entry in batch]
        log_times = [entry[2] for entry in batch]
        for i, payload in enumerate(payloads):
            if type(payload) is not bytes:
                payloads[i] = _wire_bytes(payload)
        try:
            rejected = self.writer.write_payloads(keys, payloads, log_times)
        except DataError as exc:  # the file is closed or cannot be written: batch lost
            self._in_flight = 0
            if not self._finished:
                self._report([(i, exc) for i in range(count)], keys)
            return
        except Exception as exc:  # a bug must not stop the recording thread: batch reported
            self._in_flight = 0
            error = DataError(f"batch not recorded: {type(exc).__name__}: {exc}")
            self._report([(i, error) for i in range(count)], keys)
            return
        self.written += count - len(rejected)
        self._in_flight = 0
        self._report(rejected, keys)

    def _report(self, rejected: Sequence[tuple[int, Exception]], keys: list[str]) -> None:
        self.malformed += len(rejected)
        if self._on_malformed is not None:
            for i, exc in rejected:
                self._on_malformed(keys[i], exc)

    def close(self, timeout_s: float = 30.0) -> None:
        """Write what is queued, stop the thread and close the file (idempotent)."""
        if not self._closed:
            self._closed = True
            self._stop.set()
            self._thread.join(timeout_s)
        self._finished = True
        self.writer.close()

    def stats(self) -> dict[str, Any]:
        """Counters of the recording."""
        return {
            "path": str(self.writer.path),
            "messages": self.written,
            "durable": self.writer.messages_durable,
            "backlog": self.backlog,
            "dropped": self.dropped,
            "malformed": self.malformed,
        }


def _wire_bytes(item: object) -> bytes:
    """Return the wire bytes of a submitted item: a message object or a bytes-like payload."""
    if isinstance(item, bytearray | memoryview):
        return bytes(item)
    if isinstance(item, _MESSAGE_CLASSES):
        return item.encode()
    return b""  # neither a payload nor a message: rejected as malformed
