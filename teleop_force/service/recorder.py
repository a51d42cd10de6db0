"""Record a session in a background thread, so recording never slows a Zenoh receive thread.

A subscriber callback runs on a Zenoh receive thread; while it runs, that link delivers
nothing else, and with congestion control BLOCK a slow callback ends up blocking the
*publisher* (the master's setpoints, the slave's joint states). Encoding JSON and compressing
MCAP chunks is the slow part of recording, so callbacks only hand the payload to
:meth:`BackgroundRecorder.submit` (a queue append) and one thread decodes and writes.

If the writer cannot keep up for long (``max_backlog`` queued messages), further messages are
dropped from the *recording* and counted; the live data path is never affected.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any, Final

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.transport import messages as m

#: Queued messages at most: 60 s of a 6-channel 1 kHz session.
DEFAULT_MAX_BACKLOG: Final = 360_000
_STOP: Final = object()


class BackgroundRecorder:
    """Thread writing ``(key, message or payload, log time)`` to a :class:`SessionWriter`."""

    def __init__(
        self,
        writer: SessionWriter,
        on_malformed: Callable[[str, Exception], None] | None = None,
        max_backlog: int = DEFAULT_MAX_BACKLOG,
    ) -> None:
        """Start the writing thread; ``on_malformed(key, error)`` hears of undecodable input."""
        if max_backlog < 1:
            raise ConfigurationError(f"max_backlog must be >= 1, got {max_backlog}")
        self.writer = writer
        self.max_backlog = int(max_backlog)
        self.dropped = 0
        self.written = 0
        self._on_malformed = on_malformed
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._closed = False
        self._finished = False
        self._thread = threading.Thread(target=self._run, name="recorder", daemon=True)
        self._thread.start()

    @property
    def backlog(self) -> int:
        """Messages waiting to be written."""
        return self._queue.qsize()

    def submit(self, key: str, item: m.Message | bytes, log_time_ns: int) -> None:
        """Queue one message (or a raw payload, decoded by the thread) for the recording."""
        if self._closed:
            return
        if self._queue.qsize() >= self.max_backlog:
            self.dropped += 1
            return
        self._queue.put((key, item, log_time_ns))

    def _run(self) -> None:
        while True:
            entry = self._queue.get()
            if entry is _STOP:
                return
            key, item, log_time_ns = entry
            try:
                message = m.decode(item) if isinstance(item, bytes) else item
                self.writer.write(key, message, log_time_ns)
                self.written += 1
            except (MessageError, DataError) as exc:  # bad payload, or wrong type for a channel
                if self._finished:
                    return
                if self._on_malformed is not None:
                    self._on_malformed(key, exc)

    def close(self, timeout_s: float = 30.0) -> None:
        """Write what is queued, stop the thread and close the file (idempotent)."""
        if not self._closed:
            self._closed = True
            self._queue.put(_STOP)
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
        }
