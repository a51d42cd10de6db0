"""Figure 1 of ``teleop-force bench``: the 1 kHz estimation step against a bare ``pin.rnea``.

Every :meth:`ForceEstimator.step` call (what the service runs per joint state; or
:meth:`ForceEstimator.update`, which wraps it in a :class:`ForceEstimate`) is timed on its
own while the estimator streams a recording's samples: in alternate blocks of 100 with the
wall clock (``perf_counter_ns``, the figure) and with the thread's CPU clock
(``thread_time_ns``: the same work without the time the thread waited for a core, which on a
shared machine is most of a wall p99). Between the blocks, as many ``rnea`` calls on the same
pinocchio model at the same angles are timed together, so both see the same machine load.
Reported: the call's p50 / p99 / max [µs], the mean of one ``rnea`` call, and the call's p50
as a multiple of it.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop_force.bench.measure import percentiles
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel

#: Updates per block (each timed alone), then as many ``rnea`` calls timed together.
BLOCK = 100


@dataclass(frozen=True)
class StepTiming:
    """Timing of the estimation step of one model.

    Attributes:
        samples: Updates timed with the wall clock (as many again with the CPU clock).
        p50_us, p99_us, max_us, mean_us: Update wall-time statistics [µs].
        cpu_p50_us, cpu_p99_us: Update CPU-time (thread) percentiles [µs].
        rnea_us: Mean time of one ``pin.rnea`` call on the same model [µs] (median over blocks).
        timer_overhead_us: Median of an empty ``perf_counter_ns`` pair [µs] (included above).

    """

    samples: int
    p50_us: float
    p99_us: float
    max_us: float
    mean_us: float
    cpu_p50_us: float
    cpu_p99_us: float
    rnea_us: float
    timer_overhead_us: float

    @property
    def vs_rnea(self) -> float:
        """Update p50 as a multiple of one ``rnea`` call."""
        return self.p50_us / self.rnea_us

    @property
    def p99_vs_rnea(self) -> float:
        """Update p99 as a multiple of one ``rnea`` call."""
        return self.p99_us / self.rnea_us


def _timer_overhead_ns(repeats: int = 2000) -> float:
    clock = time.perf_counter_ns
    samples = []
    for _ in range(repeats):
        start = clock()
        samples.append(clock() - start)
    return float(np.median(samples))


def time_estimation_step(
    model: DynamicModel,
    t_s: np.ndarray,
    q_rad: np.ndarray,
    tau_nm: np.ndarray,
    samples: int,
    warmup: int = 500,
    call: str = "step",
) -> StepTiming:
    """Stream ``warmup + samples`` rows of a recording through a new estimator; time each update.

    The recording is cycled if it is shorter (the estimator is reset at each wrap so time
    keeps increasing within a stream). ``call``: ``"step"`` or ``"update"``, the method timed.
    """
    if call not in ("step", "update"):
        raise ValueError(f"call must be 'step' or 'update', got {call!r}")
    estimator = ForceEstimator(model)
    robot = estimator.robot
    if robot is None:
        raise ValueError("the estimation benchmark needs a model with rigid-body terms")
    rows = t_s.size
    q_rows = [np.array(q) for q in q_rad]
    tau_rows = [np.array(t) for t in tau_nm]
    times = [float(t) for t in t_s]
    for k in range(warmup):
        if k % rows == 0:
            estimator.reset()
        estimator.update(times[k % rows], q_rows[k % rows], tau_rows[k % rows])
    pin_model, pin_data = robot.model, robot.model.createData()
    q_model = [robot.to_model(q) for q in q_rows]
    zero = np.zeros(pin_model.nv)  # model coordinates: nv > n with a parallelogram
    velocity = np.full(pin_model.nv, 0.3)
    wall_clock, cpu_clock = time.perf_counter_ns, time.thread_time_ns
    update = estimator.step if call == "step" else estimator.update
    step_ns = np.empty(samples)
    cpu_ns = np.empty(samples)
    rnea_ns: list[float] = []
    gc.collect()
    k = warmup
    done = [0, 0]  # wall-timed, CPU-timed updates
    which = 1
    while min(done) < samples:
        which = 1 - which if done[1 - which] < samples else which
        clock, out = (wall_clock, step_ns) if which == 0 else (cpu_clock, cpu_ns)
        block = min(BLOCK, samples - done[which])
        base = done[which]
        for i in range(block):
            r = k % rows
            if r == 0:
                estimator.reset()
            start = clock()
            update(times[r], q_rows[r], tau_rows[r])
            out[base + i] = clock() - start
            k += 1
        done[which] += block
        start = wall_clock()
        for i in range(block):
            pin.rnea(pin_model, pin_data, q_model[(k - block + i) % rows], velocity, zero)
        rnea_ns.append((wall_clock() - start) / block)
    p50, p99 = percentiles(step_ns, (50, 99))
    cpu_p50, cpu_p99 = percentiles(cpu_ns, (50, 99))
    return StepTiming(
        samples=samples,
        p50_us=p50 / 1e3,
        p99_us=p99 / 1e3,
        max_us=float(step_ns.max()) / 1e3,
        mean_us=float(step_ns.mean()) / 1e3,
        cpu_p50_us=cpu_p50 / 1e3,
        cpu_p99_us=cpu_p99 / 1e3,
        rnea_us=float(np.median(rnea_ns)) / 1e3,
        timer_overhead_us=_timer_overhead_ns() / 1e3,
    )
