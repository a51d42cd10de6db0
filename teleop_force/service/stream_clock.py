"""The time base of the force service's joint-state stream, and the rule that restarts it.

The service runs its estimator on ``t = (t_ns - t0_ns) * 1e-9``, counted in integer
nanoseconds from the first sample of the stream, so the same stream gives the same floats
whenever it is played (a replay shifted in time included). A new stream begins (and the
estimator is reset by the caller) at the first sample, after :meth:`StreamClock.reset`, when
the sequence restarted, or when the stamp goes backwards or pauses longer than
:data:`MAX_STREAM_PAUSE_NS`::

    clock = StreamClock()
    clock.advance(5_000_000, seq_restarted=False)   # True: the first sample starts a stream
    clock.advance(6_000_000, seq_restarted=False)   # False; clock.t_s == 0.001
    clock.advance(6_000_000, seq_restarted=False)   # True: the stamp did not increase
    clock.restarts                                  # 1 (the first stream is not a restart)
"""

from __future__ import annotations

from typing import Final

#: A pause longer than this in the joint-state stamps starts a new stream [ns].
MAX_STREAM_PAUSE_NS: Final = 500_000_000


class StreamClock:
    """Stream start ``t0_ns``, last stamp and restarts of one joint-state stream.

    Attributes:
        t0_ns: Stamp of the stream's first sample (``None``: the next sample starts one).
        last_t_ns: Stamp of the last sample seen (``None`` before the first).
        restarts: New streams begun after a first one (:meth:`reset` ones not counted).
        t_s: Time of the last sample since ``t0_ns`` [s], as the estimator is run on.

    """

    __slots__ = ("last_t_ns", "restarts", "t0_ns", "t_s")

    def __init__(self) -> None:
        """Start with no stream: the first sample begins one."""
        self.t0_ns: int | None = None
        self.last_t_ns: int | None = None
        self.restarts = 0
        self.t_s = 0.0

    def reset(self) -> None:
        """Make the next sample start a fresh stream (not counted as a restart)."""
        self.t0_ns = None

    def advance(self, t_ns: int, seq_restarted: bool) -> bool:
        """Take the next sample's stamp and set :attr:`t_s`; return whether a stream begins.

        ``seq_restarted``: the sample's sequence number went backwards or jumped far.
        """
        t0 = self.t0_ns
        last = self.last_t_ns
        if (
            t0 is None
            or seq_restarted
            or (last is not None and (t_ns <= last or t_ns - last > MAX_STREAM_PAUSE_NS))
        ):
            if t0 is not None:
                self.restarts += 1
            self.t0_ns = t0 = t_ns
            began = True
        else:
            began = False
        self.last_t_ns = t_ns
        self.t_s = (t_ns - t0) * 1e-9
        return began
