"""Train the wavelet-network friction on what the rigid-body model leaves (paper III-C, IV-B).

The rigid-body base parameters come from stage one (fitted with a coupled Coulomb-viscous
friction that absorbs friction "noise"). The networks are then trained on the filtered signals
of every recording, either by the Lyapunov law (the paper) or by the batch ridge fit of the
same basis. The stage-one coupled CV stays inside the network as the fallback it blends back
to off the trained ground: on little data (a short recording, the test stand's 0.1 s flights)
the network is trained on what there is and the model is, where the coverage map has no
trained ground, the fitted CV; :func:`coverage_warning` says so in one line.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from threadpoolctl import threadpool_limits

from teleop_force.errors import DataError
from teleop_force.friction.adaptation import LyapunovAdapter
from teleop_force.friction.batch_fit import fit_batch, wavelet_visits
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.coverage import CoverageConfig, CoverageMap
from teleop_force.friction.wavelet_network import WaveletJointSpec, WaveletNetwork
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.description import RobotDescription

if TYPE_CHECKING:
    from teleop_force.identification.prepared import PreparedRecording, WaveletOptions

#: The paper's Table IV: (finest, coarsest dilation, mu, theta) by number of inputs.
_TABLE_IV = {1: (-5, 0, 4.0e-6, 5.0e-6), 2: (-4, 0, 5.0e-5, 6.0e-5)}
#: Seconds of training data per coverage cell below which the network is not trusted at all,
#: and from which it is fully trusted (converted to samples at the data's rate).
UNTRAINED_CELL_S = 0.02
TRAINED_CELL_S = 0.2
#: Fraction of the training samples on trained ground below which a joint is reported as
#: mostly the CV fallback (:func:`coverage_warning`).
WARN_TRAINED_FRACTION = 0.5
#: The paper's adaptation gains (joint 1, joints 2 and 3).
_OMNI_GAMMA = (0.08, 0.05, 0.05)
#: The batch fit builds its normal equations from every ``row_stride``-th filtered row (the
#: wavelets are still evaluated and filtered on every sample): the largest *odd* stride with at
#: least this many rows per period of the low-pass cut-off (3 at 1 kHz and 8 Hz). Measured on
#: the benchmark's 240,000 samples against all rows (BENCHMARKS.md, identification): stride 3
#: gives the same fit to 4 digits (filtered torque within 0.12 % of the target's RMS), strides
#: sharing a factor with 10 (2, 4, 5, 6, 10: 0.6-1.7 %) pick up a periodic component of the
#: recording; an odd stride at least keeps a period-2 component from aliasing to a constant.
BATCH_ROWS_PER_CUTOFF_PERIOD = 40.0
#: Samples near a wavelet's centre for the batch fit to consider it (:func:`batch_min_visits`).
BATCH_MIN_VISITS = 200


def batch_min_visits(network: WaveletNetwork, qd_rad_s: np.ndarray) -> int:
    """Return how many samples near a wavelet's centre the batch fit needs to consider it.

    :data:`BATCH_MIN_VISITS`, lowered on little data to the best-visited wavelet's count of the
    joint that has the fewest (at least 1), so every joint keeps a candidate: a network
    trained on a short recording is then trusted only where its coverage map says so.
    """
    best = min(
        float(np.max(wavelet_visits(network, j, qd_rad_s), initial=0.0))
        for j in range(network.n_joints)
    )
    return int(max(1, min(BATCH_MIN_VISITS, best)))


def batch_row_stride(rate_hz: float, cutoff_hz: float) -> int:
    """Row stride of the batch fit's normal equations (see BATCH_ROWS_PER_CUTOFF_PERIOD)."""
    stride = max(1, int(rate_hz / (BATCH_ROWS_PER_CUTOFF_PERIOD * cutoff_hz) + 1e-9))
    return stride if stride % 2 == 1 else stride - 1


def _times(regressor: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``regressor (N, n, r) @ values (r,)`` -> (N, n), as one matrix-vector product."""
    n_rows, n_joints, r = regressor.shape
    if r == 0:
        return np.zeros((n_rows, n_joints))
    return (np.ascontiguousarray(regressor).reshape(-1, r) @ values).reshape(n_rows, n_joints)


def wavelet_specs(
    description: RobotDescription, qd_max_rad_s: np.ndarray
) -> list[WaveletJointSpec]:
    """One network per joint over the velocity region seen in training (a 10 % margin)."""
    specs = []
    for inputs in description.friction_inputs:
        limit = tuple(max(0.2, 1.1 * float(qd_max_rad_s[i])) for i in inputs)
        m_min, m_max, mu, theta = _TABLE_IV.get(len(inputs), (-3, 0, 5e-5, 6e-5))
        specs.append(
            WaveletJointSpec(inputs, tuple(-v for v in limit), limit, m_min, m_max, mu, theta)
        )
    return specs


def train_wavelet_network(
    prepared: Sequence[PreparedRecording],
    description: RobotDescription,
    base_values: np.ndarray,
    offsets_nm: np.ndarray,
    fallback: CoupledCoulombViscous,
    options: WaveletOptions,
    inertia_kgm2: np.ndarray | None = None,
    known_torque_l: Sequence[np.ndarray] | None = None,
    sample_masks: Sequence[np.ndarray] | None = None,
) -> tuple[WaveletNetwork, dict[str, Any]]:
    """Return the trained network and figures (sizes reached, speed, fit error).

    With ``options.on_fallback`` the network is trained on what ``fallback`` leaves (its
    filtered torque is subtracted from the target like ``known_torque_l``) and adds to it.

    ``inertia_kgm2`` (diagonal of ``M`` at a typical pose) weights the momentum-coordinate
    prediction error so the paper's gains keep their meaning (its error is a velocity).
    ``known_torque_l`` (one ``(N, n)`` array per recording) is filtered torque already explained
    by other terms (found effects), subtracted from the network's target. ``sample_masks``
    (one boolean ``(N,)`` per recording) keeps only those samples (besides the warm-up), e.g.
    the test stand's phases without contact; the kept samples are trained on as one stream
    (their targets are filtered over the whole recording, the network's basis over the kept
    samples). The figures include ``wn_trained_fraction`` per joint and, when a joint is
    mostly off the trained ground, ``warning`` (:func:`coverage_warning`).
    """
    masks = [p.signals.valid for p in prepared]
    if sample_masks is not None:
        masks = [
            valid & np.asarray(m, dtype=bool) for valid, m in zip(masks, sample_masks, strict=True)
        ]
    if not any(bool(m.any()) for m in masks):
        raise DataError("no samples to train the wavelet network on")
    kept_qd = np.concatenate([p.signals.qd_rad_s[m] for p, m in zip(prepared, masks, strict=True)])
    qd_max = np.max(np.abs(kept_qd), axis=0)
    specs = wavelet_specs(description, qd_max)
    rate_hz = 1.0 / float(np.median(np.diff(prepared[0].signals.t_s)))
    coverage = CoverageMap.for_inputs(
        [s.inputs for s in specs],
        [s.x_min_rad_s for s in specs],
        [s.x_max_rad_s for s in specs],
        CoverageConfig(
            untrained_density=UNTRAINED_CELL_S * rate_hz, trained_density=TRAINED_CELL_S * rate_hz
        ),
    )
    network = WaveletNetwork(
        description.n_joints,
        specs,
        fallback=fallback,
        coverage=coverage,
        on_fallback=options.on_fallback,
    )
    details: dict[str, Any] = {"wn_method": options.method, "wn_on_fallback": options.on_fallback}
    known: list[Any] = list(known_torque_l) if known_torque_l is not None else [0.0] * len(prepared)
    if network.on_fallback:
        known = [
            extra
            + lowpass_batch(
                network.path_base_torque(p.signals.q_rad, p.signals.qd_rad_s),
                p.signals.t_s,
                p.signals.config.cutoff_hz,
            )
            for p, extra in zip(prepared, known, strict=True)
        ]
    if options.method == "batch":
        t_all, qd_all, target_all = [], [], []
        t_offset = 0.0
        for item, extra, mask in zip(prepared, known, masks, strict=True):
            s = item.signals
            if not mask.any():
                continue
            with threadpool_limits(limits=1, user_api="blas"):
                rigid = _times(s.y_derivative, base_values) + _times(s.y_lowpassed, base_values)
            target = (
                s.tau_lowpassed_nm
                - extra
                - rigid
                - lowpass_batch(
                    np.broadcast_to(offsets_nm, s.qd_rad_s.shape), s.t_s, s.config.cutoff_hz
                )
            )
            t_all.append(s.t_s[mask] - s.t_s[0] + t_offset)
            t_offset = t_all[-1][-1] + float(np.median(np.diff(s.t_s)))
            qd_all.append(s.qd_rad_s[mask])
            target_all.append(target[mask])
        cutoff_hz = prepared[0].signals.config.cutoff_hz
        min_visits = batch_min_visits(network, kept_qd)
        if min_visits < BATCH_MIN_VISITS:
            details["wn_min_visits"] = min_visits
        result = fit_batch(
            network,
            np.concatenate(t_all),
            np.concatenate(qd_all),
            np.concatenate(target_all),
            cutoff_hz,
            fit_fallback=False,
            ridge=1e-5,
            min_visits=min_visits,
            row_stride=batch_row_stride(rate_hz, cutoff_hz),
        )
        details.update(
            wn_sizes=list(result.sizes),
            wn_fit_relative_rms=[round(float(x), 4) for x in result.relative_rms],
            wn_wall_time_s=round(result.wall_time_s, 3),
        )
        return network, _with_coverage(details, network, kept_qd)
    gamma = _OMNI_GAMMA if description.n_joints == 3 else 0.05
    inertia = 1e-3 if inertia_kgm2 is None else inertia_kgm2
    adapter = LyapunovAdapter(
        network, -300.0, gamma, 100.0, prepared[0].signals.config.cutoff_hz, inertia_kgm2=inertia
    )
    wall = 0.0
    samples = 0
    sizes_history: list[list[int]] = []
    for _ in range(options.passes):
        for item, extra, v in zip(prepared, known, masks, strict=True):
            s = item.signals
            if not v.any():
                continue
            p_l = np.einsum("kjp,p->kj", s.y_momentum_lowpassed, base_values)
            w_l = np.einsum("kjp,p->kj", s.y_lowpassed, base_values) + lowpass_batch(
                np.broadcast_to(offsets_nm, s.qd_rad_s.shape), s.t_s, s.config.cutoff_hz
            )
            u_l = s.tau_lowpassed_nm - extra - w_l
            run = adapter.run(s.t_s[v], s.qd_rad_s[v], p_l[v], u_l[v])
            wall += run.wall_time_s
            samples += run.samples
            sizes_history.append([int(x) for x in run.final_sizes])
    details.update(
        wn_sizes=list(network.parameter_counts()),
        wn_sizes_history=sizes_history,
        wn_adaptation_samples_per_s=round(samples / wall if wall > 0 else float("inf")),
    )
    return network, _with_coverage(details, network, kept_qd)


def trained_fractions(network: WaveletNetwork, qd_rad_s: np.ndarray) -> np.ndarray:
    """Per joint, the fraction of ``qd_rad_s`` (N x n) where the network is trusted (>= 0.5)."""
    if network.coverage is None:
        return np.ones(network.n_joints)
    return np.array(
        [network.coverage.fraction_on_trained_ground(qd_rad_s, j) for j in range(network.n_joints)]
    )


def coverage_warning(fractions: np.ndarray, joint_names: Sequence[str] | None = None) -> str | None:
    """One line when a joint's network is trusted on under half its training samples, else None.

    There the model's friction is the stage-one Coulomb-viscous fallback, fitted on the same
    data (the coverage-aware blend): identification does not refuse, it says so.
    """
    low = [j for j, f in enumerate(fractions) if f < WARN_TRAINED_FRACTION]
    if not low:
        return None
    names = [
        f"{joint_names[j] if joint_names else f'joint {j + 1}'} {fractions[j]:.0%}" for j in low
    ]
    return (
        "wavelet network on trained ground for only "
        + ", ".join(names)
        + " of the training samples: off it the friction is the fitted Coulomb-viscous fallback"
    )


def _with_coverage(
    details: dict[str, Any], network: WaveletNetwork, qd_rad_s: np.ndarray
) -> dict[str, Any]:
    fractions = trained_fractions(network, qd_rad_s)
    details["wn_trained_fraction"] = [round(float(f), 3) for f in fractions]
    warning = coverage_warning(fractions)
    if warning is not None:
        details["warning"] = warning
    return details
