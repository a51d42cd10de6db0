"""Inputs of ``teleop-force bench``: simulated recordings, the benchmark model, replay files.

Everything is generated, so a benchmark needs no data files and every run sees the same
inputs (fixed seeds):

* identification data: the paper's rigid-body multisine (two seeds), simulated for two of
  its 22 s periods on the simulated Omni, the last period repeated to the wanted length
  (the simulator runs ~5-10x real time: 240 s would cost the benchmark more than what it
  measures);
* the benchmark model: what ``identify`` makes of that data with the wavelet-network friction
  (batch fit, several hundred wavelets per joint), plus two found effects;
* model variants with 100 / 300 / 1000 wavelets per joint network (:func:`with_wavelets`);
* replay sessions: a simulated palpation (the full length, no repetition) written as an MCAP
  session with the demo's message mix (slave and master joint states, setpoints, true
  contact force, status); shorter sessions are its prefixes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect
from teleop_force.io.interchange_csv import Recording
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.transport import keys
from teleop_force.transport import messages as m

#: Sample interval of every generated recording [s].
SAMPLE_INTERVAL_S = 1e-3
#: Stamp of the first sample of a generated replay session [ns].
_EPOCH_NS = 1_700_000_000_000_000_000
#: Status messages per second in a generated session (the slave's rate in the demo).
_STATUS_HZ = 20


#: Period of the rigid-body multisine: its frequencies are multiples of 1/22 Hz.
MULTISINE_PERIOD_S = 22.0


def identification_recordings(
    simulated_s: float, samples_per_recording: int, seed: int = 0
) -> list[Recording]:
    """Two rigid-body multisine recordings (seeds ``seed``, ``seed + 1``) of the given length.

    Each is simulated for ``simulated_s`` seconds. If that is the whole length, it is used
    as is; otherwise, since the multisine repeats every 22 s, the last whole period of a
    simulation of two periods or more (past the start transient) is repeated to the length:
    the seams are continuous up to the plant's period-to-period differences and the data stay
    physically consistent (a seam with a jump would put a spike in the velocities, which
    sets the wavelet networks' regions).

    Raises:
        ValueError: when ``simulated_s`` is neither the whole length nor two periods.

    """
    from teleop_force.simulation import rigid_body_protocol

    period = round(MULTISINE_PERIOD_S / SAMPLE_INTERVAL_S)
    t = (np.arange(samples_per_recording) * SAMPLE_INTERVAL_S).astype(np.float64)
    recordings = []
    for offset in (0, 1):
        session = rigid_body_protocol(simulated_s, seed + offset)
        if session.n_samples >= samples_per_recording:
            tile = slice(0, samples_per_recording)
        elif session.n_samples >= 2 * period:
            tile = slice(session.n_samples - period, session.n_samples)
        else:
            raise ValueError(
                f"simulate the whole {samples_per_recording / 1000:g} s or at least two "
                f"{MULTISINE_PERIOD_S:g} s periods, not {simulated_s:g} s"
            )

        def tiled(x: np.ndarray, tile: slice = tile) -> np.ndarray:
            return np.resize(x[tile], (samples_per_recording, x.shape[1]))

        recordings.append(
            Recording(
                t_s=t,
                q_rad=tiled(session.q_rad),
                tau_nm=tiled(session.tau_nm),
                f_tip_in_base_n=tiled(session.f_tip_in_base_n),
                source=Path(f"<simulated {session.name} seed {seed + offset}>"),
            )
        )
    return recordings


def with_found_effects(model: DynamicModel) -> DynamicModel:
    """``model`` plus two found effects (a position-periodic torque, a Stribeck friction)."""
    effects = (
        FoundEffect(
            BasisSpec(1, "q2", "periodic", frequency=2.0, harmonics=3),
            np.array([2e-3, -1e-3, 5e-4, 1e-3, 5e-4, -2e-4]),
        ),
        FoundEffect(
            BasisSpec(2, "qd3", "stribeck", "sign", scales=(0.05, 0.2)), np.array([2e-3, 1e-3])
        ),
    )
    return dataclasses.replace(model, effects=tuple(model.effects) + effects)


def wavelet_counts(model: DynamicModel) -> list[int]:
    """Active wavelets per joint network (empty without a wavelet-network friction)."""
    friction = model.friction
    return list(friction.parameter_counts()) if isinstance(friction, WaveletNetwork) else []


def with_wavelets(model: DynamicModel, per_joint: int, seed: int = 0) -> DynamicModel:
    """Copy ``model``, giving its networks ``per_joint`` active wavelets each.

    The identified wavelets are kept (a random subset of them when fewer are wanted); more
    come at random from the pool, with coefficients of the identified ones' typical size.
    A joint whose pool is smaller than ``per_joint`` gets its whole pool. Meant for timing
    and memory: the extra wavelets make no sense physically.
    """
    if not isinstance(model.friction, WaveletNetwork):
        raise TypeError("with_wavelets needs a wavelet-network model")
    network = WaveletNetwork.from_dict(model.friction.to_dict())
    rng = np.random.default_rng(seed)
    pool = network.pool
    for j in range(network.n_joints):
        sl = pool.joint_slice(j)
        active = network.active_global_indices(j)
        coefficients = network.coefficients_at(active)
        scale = float(np.median(np.abs(coefficients))) if coefficients.size else 1e-4
        want = min(per_joint, pool.joint_size(j))
        if want <= active.size:
            keep = np.sort(rng.choice(active.size, size=want, replace=False))
            network.set_structure(j, active[keep], coefficients[keep])
            continue
        others = np.setdiff1d(np.arange(sl.start, sl.stop), active)
        extra = np.sort(rng.choice(others, size=want - active.size, replace=False))
        indices = np.concatenate((active, extra))
        values = np.concatenate((coefficients, rng.normal(0.0, scale, extra.size)))
        order = np.argsort(indices)
        network.set_structure(j, indices[order], values[order])
    return dataclasses.replace(model, friction=network)


def write_replay_session(
    path: Path,
    t_s: np.ndarray,
    q_rad: np.ndarray,
    qd_rad_s: np.ndarray,
    tau_nm: np.ndarray,
    q_ref_rad: np.ndarray,
    force_n: np.ndarray,
    model_path: str = "",
) -> int:
    """Write a session MCAP with the demo's message mix; return the number of messages.

    Per sample: the slave's joint state (``q``, ``qd``, ``effort = tau``) and true contact
    force, the master's joint state and setpoint (``q_ref``); the slave's status at 20 Hz.
    """
    slave, master = "slave", "master"
    topics = {
        "js": keys.measured_js(slave),
        "cf": keys.measured_cf(slave),
        "mjs": keys.measured_js(master),
        "sp": keys.setpoint_js(master),
        "st": keys.status(slave),
    }
    metadata = {
        "primary_device": slave,
        "master_device": master,
        "source": "live",
        "robot": "omni",
        "model": model_path,
        "recorder": "teleop_force.bench.main",
    }
    status_every = max(1, round(1.0 / (_STATUS_HZ * SAMPLE_INTERVAL_S)))
    zeros = (0.0,) * q_rad.shape[1]
    written = 0
    with SessionWriter(path, metadata) as writer:
        for k in range(t_s.size):
            stamp = _EPOCH_NS + round(float(t_s[k]) * 1e9)
            q, q_ref = tuple(q_rad[k].tolist()), tuple(q_ref_rad[k].tolist())
            batch: Sequence[tuple[str, m.Message]] = (
                (topics["mjs"], m.JointState(k, stamp, q_ref, zeros, zeros)),
                (topics["sp"], m.JointSetpoint(k, stamp, q_ref)),
                (
                    topics["js"],
                    m.JointState(
                        k, stamp, q, tuple(qd_rad_s[k].tolist()), tuple(tau_nm[k].tolist())
                    ),
                ),
                (topics["cf"], m.ContactForce(k, stamp, tuple(force_n[k].tolist()))),
            )
            for topic, message in batch:
                writer.write(topic, message, stamp)
            written += len(batch)
            if k % status_every == 0:
                status = m.Status(k // status_every, stamp, m.SafetyState.FOLLOWING)
                writer.write(topics["st"], status, stamp)
                written += 1
    return written


def palpation_arrays(duration_s: float, seed: int = 0) -> dict[str, np.ndarray]:
    """Simulate a palpation of ``duration_s``: the arrays of a replay session."""
    from teleop_force.simulation import palpation_protocol

    session = palpation_protocol(duration_s, seed)
    return {
        "t_s": np.asarray(session.t_s),
        "q_rad": session.q_rad,
        "qd_rad_s": session.qd_true_rad_s,
        "tau_nm": session.tau_nm,
        "q_ref_rad": session.q_ref_rad,
        "force_n": session.f_tip_in_base_n,
    }
