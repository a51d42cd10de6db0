"""What the force service records: the open recording, its subscriptions, the last one closed.

The recording itself (a :class:`~teleop_force.service.ros2_recorder.Ros2Recorder`) is opened
and closed by the service, at start-up (``--record``) or on request; :class:`RecordingState`
keeps track of it for the service's callbacks and statistics.
"""

from __future__ import annotations

from typing import Any

from teleop_force.service.ros2_recorder import Ros2Recorder


class RecordingState:
    """The recording open (if any), the floor's subscriptions, and the last one's counters.

    Attributes:
        recorder: The recording open (``None``: not recording).
        entities: The Zenoh floor's subscription to the recorded keys (the recorder has its own).
        last: Final counters of the last recording closed (``None``: none yet).

    """

    __slots__ = ("entities", "last", "recorder")

    def __init__(self) -> None:
        """Start not recording."""
        self.recorder: Ros2Recorder | None = None
        self.entities: list[Any] = []
        self.last: dict[str, Any] | None = None

    def take_entities(self) -> list[Any]:
        """Return the subscriptions to undeclare, and forget them."""
        entities, self.entities = self.entities, []
        return entities

    def current_stats(self) -> dict[str, Any] | None:
        """Return the ``recording`` statistics: the open recording's counters, or ``None``."""
        recorder = self.recorder
        return None if recorder is None else recorder.stats()
