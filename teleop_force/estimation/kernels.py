"""The compiled estimator step (numba): every per-sample term of the model, no Python per term.

At 1 kHz the estimator evaluates the whole model on *one* sample, where NumPy's per-call
overhead (~1 µs) would dwarf the arithmetic. So a sample crosses into compiled code twice,
around pinocchio's calls (which stay outside, :class:`~teleop_force.estimation.estimator.
ForceEstimator`):

* :func:`prefilter_step`: checks the sample, runs the pre-filter on the angles and torques
  (``L_v``, or the observer's own one or two stages) and the backward difference of the
  filtered angles, and writes pinocchio's inputs
  (model-coordinate angles and velocities, the raw angles for the Jacobian);
* :func:`finish_step`: the rigid-body terms from pinocchio's ``M``, ``C``, ``g``
  (:func:`rigid_terms_into`), the second filter ``L``, friction (Coulomb-viscous term tables,
  or a wavelet network blended with its fallback by the coverage trust), offsets and found
  effects (:func:`add_model_terms`, the friction and the effects' ``sgn(qd)`` ramped to 0 in
  the standstill band, or the Coulomb terms' sticking state advanced instead), the
  external torque (the filtered dynamics, or the momentum observer of
  :mod:`teleop_force.estimation.momentum_observer`, as the model's filter configuration
  says) and ``F = J^-T tau_ext`` (:func:`tip_force_into`).

The terms are the single definitions of :mod:`teleop_force.friction.terms` and
:mod:`teleop_force.identification.effect_terms`, which the batch methods call too; the model
is encoded in arrays (term tables, wavelet table, coverage grids, effect codes) by
:class:`ModelTerms`, which also follows later changes of the model (online adaptation, a new
coverage count). Nothing is allocated per sample in compiled code: state, inputs and outputs
are preallocated arrays.

Friction classes without a term encoding are evaluated by their own vectorised methods on a
one-row array between the two steps (passed in as ``extra``), so the estimator stays correct
for every model.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ModelError
from teleop_force.estimation.momentum_observer import (
    butterworth_step_into,
    observer_update_into,
)
from teleop_force.friction.coverage import CoverageMap
from teleop_force.friction.terms import (
    coverage_trust_into,
    linear_friction_torque_into,
    standstill_factor,
    standstill_scale_into,
    sticking_friction_torque_into,
    sticking_update_into,
    term_velocity,
    trust_add,
    trust_blend,
    wavelet_network_torque_into,
)
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel, sticking_rad_of
from teleop_force.identification.effect_terms import add_effects_torque_into
from teleop_force.identification.effects import effects_table

#: Friction modes of :func:`add_model_terms`.
FRICTION_NONE, FRICTION_LINEAR, FRICTION_NETWORK, FRICTION_NETWORK_ON_FALLBACK = 0, 1, 2, 3
#: What :func:`finish_step`'s ``rigid`` says: no rigid body, pinocchio's ``M``, ``C``, ``g`` in
#: ``mass``, ``coriolis``, ``gravity``, or (the fused step) ``mass`` rows ``[M v, g - C^T v]``
#: already computed in model coordinates.
RIGID_NONE, RIGID_MATRICES, RIGID_MOMENTA = 0, 1, 2
#: Status codes of :func:`prefilter_step`.
STEP_OK, STEP_NON_FINITE, STEP_TIME_NOT_INCREASING = 0, 1, 2
#: Slots of the estimator state before the filter states: has a previous sample, its time,
#: the stream's first time.
STATE_HEAD = 3


def state_size(n: int, sticking_terms: int = 0) -> int:
    """Length of the estimator state (head, filters, q, qd, observer; see prefilter_step).

    ``sticking_terms``: the terms of a friction with a sticking state, whose state
    (:func:`~teleop_force.friction.terms.sticking_update_into`) ends the estimator's.
    """
    return STATE_HEAD + 15 * n + (1 + 2 * sticking_terms if sticking_terms > 0 else 0)


def output_size(n: int) -> int:
    """Length of the step's output ``[F (3), tau_ext, tau_L, tau_model, weight, singular]``."""
    return 4 + 4 * n


# -- the model's terms at one sample -----------------------------------------------------------


@njit_cached()
def add_model_terms(
    t: float,
    q: np.ndarray,
    qd: np.ndarray,
    load: np.ndarray,
    other: np.ndarray,
    weight: np.ndarray,
    network: np.ndarray,
    work: np.ndarray,
    sticking_z: np.ndarray,
    mode: int,
    offsets: np.ndarray,
    linear_table: np.ndarray,
    linear_parameters: np.ndarray,
    wavelet_inputs: np.ndarray,
    wavelet_table: np.ndarray,
    wavelet_runs: np.ndarray,
    wavelet_psi: np.ndarray,
    grid_ints: np.ndarray,
    grid_floats: np.ndarray,
    grid_values: np.ndarray,
    effect_codes: np.ndarray,
    effect_floats: np.ndarray,
    standstill_band_rad_s: float,
    sticking_inv_rad: float,
) -> None:  # pragma: no cover - compiled
    """Write friction + offsets + found effects to ``other`` and the coverage trust to ``weight``.

    ``mode``: no friction, a Coulomb-viscous term table (``linear_table`` = ``[rows | reach]``,
    (T, 2 n)), or a wavelet table blended with its fallback term table by the trust of the
    coverage grids (``grid_ints`` with no rows: trust 1), or a wavelet table added to its
    fallback times that trust (``FRICTION_NETWORK_ON_FALLBACK``). The friction, and the
    direction-dependent part of the effects (their ``sgn(qd)``: friction the residual loop
    found), are ramped to 0 below the standstill band
    (:func:`~teleop_force.friction.terms.standstill_factor`; 0: off). With a sticking state
    (``sticking_inv_rad`` = 1 / the transition angle > 0) the term table's ``sgn(w_t)`` are
    its Dahl states ``sticking_z`` (T, advanced by the caller) and the term table's friction is
    not ramped (the state holds the friction at rest); a network's part and the effects still
    are. ``network`` (n) and
    ``work`` are scratch.
    """
    n = q.size
    for j in range(n):
        other[j] = 0.0
        weight[j] = 1.0
    rows = linear_table[:, :n]
    reach = linear_table[:, n:]
    sticking = sticking_inv_rad > 0.0
    standstill = standstill_factor(qd, standstill_band_rad_s)
    # the term table: the friction, or a network's fallback (no rows without friction)
    if sticking:
        sticking_friction_torque_into(qd, rows, reach, linear_parameters, sticking_z, other)
    else:
        linear_friction_torque_into(qd, rows, reach, linear_parameters, other)
    if mode >= FRICTION_NETWORK:  # a network, blended with or added to its fallback
        for j in range(n):
            network[j] = 0.0
        wavelet_network_torque_into(
            qd, wavelet_inputs, wavelet_table, wavelet_runs, wavelet_psi, network
        )
        if grid_ints.shape[0] > 0:
            coverage_trust_into(qd, grid_ints, grid_floats, grid_values, weight)
        if sticking:  # the network's part is ramped, the fallback's sticking part is not
            for j in range(n):
                network[j] = network[j] * standstill
        if mode == FRICTION_NETWORK_ON_FALLBACK:
            for j in range(n):
                other[j] = trust_add(weight[j], network[j], other[j])
        else:
            for j in range(n):
                other[j] = trust_blend(weight[j], network[j], other[j])
    friction_scale = 1.0 if sticking else standstill
    for j in range(n):
        other[j] = other[j] * friction_scale + offsets[j]
    add_effects_torque_into(effect_codes, effect_floats, t, q, qd, load, standstill, work, other)


class _CoverageGrids:
    """A :class:`CoverageMap` as the grid table of :func:`coverage_trust_into`, kept current."""

    def __init__(self, coverage: CoverageMap) -> None:
        self.coverage = coverage
        n = coverage.n_joints
        geometry = [coverage.grid_geometry(j) for j in range(n)]
        dmax = max(g[0].size for g in geometry)
        self.ints = np.zeros((n, 2 + 2 * dmax), dtype=np.int64)
        self.floats = np.zeros((n, 2 + 2 * dmax))
        config = coverage.config
        for j, (inputs, lo, cell, shape) in enumerate(geometry):
            d = inputs.size
            self.ints[j, 0] = d
            self.ints[j, 2 : 2 + d] = inputs
            self.ints[j, 2 + dmax : 2 + dmax + d] = shape
            self.floats[j, :2] = (config.untrained_density, config.trained_density)
            self.floats[j, 2 : 2 + d] = lo
            self.floats[j, 2 + dmax : 2 + dmax + d] = cell
        self.version = -1
        self.values = np.zeros(0)

    def refresh(self) -> None:
        """Re-read the density grids if the counts changed."""
        coverage = self.coverage
        if coverage.version == self.version:
            return
        chunks = []
        offset = 0
        for j in range(coverage.n_joints):
            self.ints[j, 1] = offset
            chunks.append(np.asarray(coverage.density_grid(j), dtype=float).reshape(-1))
            offset += chunks[-1].size
        self.values = np.ascontiguousarray(np.concatenate(chunks))
        self.version = coverage.version


_UNSET = object()
_NO_INTS = np.zeros((0, 4), dtype=np.int64)
_NO_FLOATS = np.zeros((0, 4))
_NO_VALUES = np.zeros(0)
_NO_LINEAR = np.zeros((0, 2))
_NO_PARAMETERS = np.zeros(0)
_NO_WAVELET_INPUTS = np.zeros((0, 1), dtype=np.int64)
_NO_RUNS = np.zeros((0, 2), dtype=np.int64)


class ModelTerms:
    """A model's friction, offsets and found effects encoded for :func:`add_model_terms`.

    :meth:`arguments` gives the kernel's arguments for the next sample (the model's standstill
    band, from its filter configuration, and the sticking state's ``1 / phi`` last; the state
    itself is the caller's, per stream), following later
    changes of the model's friction: new parameters (read live), a network's new structure or
    coefficients, a replaced fallback or coverage map, new coverage counts. Calling the object
    evaluates one sample (tests and one-off use; the estimator calls the step kernels); with a
    sticking state, successive calls are successive samples of one stream
    (:meth:`reset_sticking` begins another).
    """

    def __init__(self, model: DynamicModel) -> None:
        """Encode ``model``'s terms (ModelError: an effect outside the model's joints)."""
        self.model = model
        self.n = n = model.n_joints
        self.friction = model.friction
        #: The standstill dead band of the friction [rad/s] (0: off).
        self.standstill_band_rad_s = float(model.filter_config.standstill_band_rad_s)
        table = effects_table(model.effects, n)
        self.effect_codes, self.effect_floats = table.codes, table.floats
        self.work = np.zeros(table.work.size)
        self._io = np.zeros(1 + 6 * n + table.work.size)
        self._out = slice(1 + 3 * n, 1 + 5 * n)
        self.network = self.friction if isinstance(self.friction, WaveletNetwork) else None
        self._linear = None if self.network is not None else _term_table(self.friction, n)
        #: Whether the friction has no term encoding (evaluated in Python, :meth:`python_friction`).
        self.python_friction = self.network is None and self._linear is None
        self._fallback: Any = _UNSET  # what the tables below were built for
        self._coverage: Any = _UNSET
        self._grids: _CoverageGrids | None = None
        self._fallback_table = np.zeros((0, 2 * n))
        self._network_arguments: tuple[Any, ...] | None = None
        self._psi = np.zeros(0)  # the wavelets' scratch
        self._versions: tuple[int, int, int] = (-1, -1, -1)
        table_friction = self.friction if self.network is None else self.network.fallback
        self._table_friction = table_friction
        sticking_table = _term_table(table_friction, n)
        rad = 0.0 if sticking_table is None else sticking_rad_of(self.friction)
        #: ``1 / transition angle`` [1/rad] of the term table's sticking state (0: none), the
        #: rows of its terms (the angle forms the state follows; none without a state) and
        #: their number (the state's size, :func:`state_size`). Read here, once.
        self.sticking_inv_rad = 1.0 / rad if rad > 0.0 else 0.0
        self.sticking_rows = np.zeros((0, n))
        if sticking_table is not None and rad > 0.0:
            self.sticking_rows = np.ascontiguousarray(sticking_table[:, :n])
        self.sticking_terms = self.sticking_rows.shape[0]
        self._sticking_state = np.zeros(1 + 2 * self.sticking_terms)
        self._fixed: tuple[Any, ...] = (
            FRICTION_NONE if self._linear is None else FRICTION_LINEAR,
            model.offsets_nm,
            _NO_LINEAR if self._linear is None else self._linear,
            _NO_PARAMETERS if self._linear is None else self.friction.parameters,
            _NO_WAVELET_INPUTS, _NO_FLOATS, _NO_RUNS, _NO_VALUES, _NO_INTS, _NO_FLOATS,
            _NO_VALUES,
            self.effect_codes, self.effect_floats, self.standstill_band_rad_s,
            self.sticking_inv_rad,
        )  # fmt: skip

    def _refresh_network(self, network: WaveletNetwork) -> None:
        """(Re)build the tables of the network's fallback and coverage map."""
        fallback = network.fallback
        if fallback is None:
            raise ModelError("wn: blended_torque needs a fitted coupled-CV fallback model")
        table = _term_table(fallback, self.n)
        if table is None:
            raise ModelError(f"wn: fallback {fallback.kind} has no Coulomb-viscous terms")
        rad = sticking_rad_of(fallback)
        if (1.0 / rad if rad > 0.0 else 0.0) != self.sticking_inv_rad:
            raise ModelError("wn: a new fallback may not change the sticking transition angle")
        self._fallback, self._fallback_table = fallback, table
        coverage = network.coverage
        self._coverage = coverage
        self._grids = None if coverage is None else _CoverageGrids(coverage)
        self._versions = (-1, -1, -1)

    def term_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the Coulomb-viscous terms: ``rows``, ``reach`` and their live ``parameters``.

        The friction's own, or a network's fallback (the table the friction modes evaluate
        without the network); no terms for a friction without one.
        """
        n = self.n
        friction = self._table_friction
        table = None if friction is None else _term_table(friction, n)
        if friction is None or table is None:
            return np.zeros((0, n)), np.zeros((0, n)), np.zeros(0)
        parameters = np.ascontiguousarray(friction.parameters, dtype=float)
        return np.ascontiguousarray(table[:, :n]), np.ascontiguousarray(table[:, n:]), parameters

    def arguments(self) -> tuple[Any, ...]:
        """Return the model's arguments of :func:`add_model_terms` (``mode`` ... ``1 / phi``)."""
        network = self.network
        if network is None:
            if self._linear is not None and self._fixed[3] is not self.friction.parameters:
                fixed = list(self._fixed)
                fixed[3] = self.friction.parameters
                self._fixed = tuple(fixed)
            return self._fixed
        if network.fallback is not self._fallback or network.coverage is not self._coverage:
            self._refresh_network(network)
        grids = self._grids
        coverage_version = -1 if grids is None else grids.coverage.version
        versions = (network.structure_version, network.coef_version, coverage_version)
        arguments = self._network_arguments
        if (
            arguments is None
            or versions != self._versions
            or arguments[3] is not self._fallback.parameters  # replaced, not changed
        ):
            if grids is not None:
                grids.refresh()
                grid_ints, grid_floats, values = grids.ints, grids.floats, grids.values
            else:
                grid_ints, grid_floats, values = _NO_INTS, _NO_FLOATS, _NO_VALUES
            inputs, wavelets, runs = network.streaming_table()
            if self._psi.size != inputs.shape[0]:
                self._psi = np.zeros(inputs.shape[0])
            self._versions = versions
            arguments = self._network_arguments = (
                FRICTION_NETWORK_ON_FALLBACK if network.on_fallback else FRICTION_NETWORK,
                self.model.offsets_nm, self._fallback_table,
                self._fallback.parameters, inputs, wavelets, runs, self._psi, grid_ints,
                grid_floats, values, self.effect_codes, self.effect_floats,
                self.standstill_band_rad_s, self.sticking_inv_rad,
            )  # fmt: skip
        return arguments

    def reset_sticking(self) -> None:
        """Begin a new stream of the sticking state of :meth:`__call__` (``z = 0``)."""
        self._sticking_state[:] = 0.0

    def python_terms(self, qd: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Friction torque and coverage weight (n each) of a friction without term encoding.

        The torque is ramped by the standstill band as :func:`add_model_terms` ramps its own.
        """
        row = np.asarray([qd], dtype=float)
        torque = np.ascontiguousarray(self.model.friction_torque(row)[0], dtype=float)
        standstill_scale_into(row[0], self.standstill_band_rad_s, torque)
        return (
            torque,
            np.ascontiguousarray(self.friction.coverage_weight(row)[0], dtype=float),
        )

    def __call__(
        self, t: float, q: Sequence[float], qd: Sequence[float], load: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """``(friction + offsets + effects, coverage weight)`` per joint at one sample.

        ``t`` is the time since the stream's first sample, ``load`` the filtered rigid-body
        model torque (the effects' ``tau<j>``).
        """
        n = self.n
        io = self._io
        io[: 1 + 3 * n] = [t, *q, *qd, *load]
        arguments = self.arguments()
        state = self._sticking_state
        if self.sticking_inv_rad > 0.0:
            sticking_update_into(io[1 : 1 + n], self.sticking_rows, self.sticking_inv_rad, state)
        add_model_terms(
            t, io[1 : 1 + n], io[1 + n : 1 + 2 * n], io[1 + 2 * n : 1 + 3 * n],
            io[1 + 3 * n : 1 + 4 * n], io[1 + 4 * n : 1 + 5 * n], io[1 + 5 * n : 1 + 6 * n],
            io[1 + 6 * n :], state[1 + self.sticking_terms :], *arguments,
        )  # fmt: skip
        out = io[self._out].tolist()
        other, weight = out[:n], out[n:]
        if self.python_friction:
            torque, weight_array = self.python_terms(qd)
            other = [o + f for o, f in zip(other, torque.tolist(), strict=True)]
            weight = weight_array.tolist()
        return other, weight


def _term_table(friction: object, n: int) -> np.ndarray | None:
    """``[rows | reach]`` (T, 2 n) of a Coulomb-viscous friction model; None for others."""
    term_table = getattr(friction, "term_table", None)
    if term_table is None:
        return None
    rows, reach = term_table()
    return np.ascontiguousarray(np.concatenate((rows, reach), axis=1), dtype=float)


# -- the rigid body and the tip ------------------------------------------------------------------


@njit_cached()
def linear_map_into(matrix: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``out = matrix @ x`` over the nonzero entries of a small matrix."""
    for i in range(matrix.shape[0]):
        out[i] = term_velocity(matrix[i], x)


@njit_cached(inline="always")
def _add_model_coordinate(
    i: int, p: float, w: float, coupling: np.ndarray, momentum: np.ndarray, other: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Add model coordinate ``i``'s momentum ``p`` and torque ``w`` through ``T^T``."""
    for j in range(coupling.shape[1]):
        t = coupling[i, j]
        if t == 1.0:
            momentum[j] += p
            other[j] += w
        elif t != 0.0:
            momentum[j] += t * p
            other[j] += t * w


@njit_cached()
def rigid_terms_into(
    q: np.ndarray,
    qd: np.ndarray,
    v_model: np.ndarray,
    mass: np.ndarray,
    coriolis: np.ndarray,
    gravity: np.ndarray,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
    momentum: np.ndarray,
    other: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Momentum and ``-C^T qd + N + springs`` in motor coordinates, at one sample.

    ``v_model = T qd``; ``mass`` (upper triangle valid), ``coriolis``, ``gravity`` are
    pinocchio's in model coordinates, ``coupling`` is ``T`` (n_model, n), ``springs`` rows
    ``[joint, stiffness, rest angle]``. Writes ``momentum = T^T M v_model + rotor qd`` and
    ``other = T^T (g - C^T v_model) + springs``.
    """
    n_model = coupling.shape[0]
    _start_motor_terms(qd, rotor, momentum, other)
    for i in range(n_model):
        p = 0.0
        w = 0.0
        for j in range(n_model):
            p += (mass[i, j] if i <= j else mass[j, i]) * v_model[j]
            w += coriolis[j, i] * v_model[j]
        _add_model_coordinate(i, p, gravity[i] - w, coupling, momentum, other)
    _add_springs(q, springs, other)


@njit_cached()
def momenta_to_motor_into(
    q: np.ndarray,
    qd: np.ndarray,
    momenta: np.ndarray,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
    momentum: np.ndarray,
    other: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """:func:`rigid_terms_into` from ``momenta`` = rows ``[M v_model, g - C^T v_model]``.

    The model-coordinate terms as the compiled chain gives them
    (:func:`~teleop_force.estimation.rigid_chain.chain_momentum_into`), mapped to motor
    coordinates with ``T^T``, the rotor inertia and the springs.
    """
    _start_motor_terms(qd, rotor, momentum, other)
    for i in range(coupling.shape[0]):
        _add_model_coordinate(i, momenta[0, i], momenta[1, i], coupling, momentum, other)
    _add_springs(q, springs, other)


@njit_cached(inline="always")
def _start_motor_terms(
    qd: np.ndarray, rotor: np.ndarray, momentum: np.ndarray, other: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Start the motor-coordinate terms: the rotors' momentum, no torque."""
    for j in range(momentum.size):
        momentum[j] = rotor[j] * qd[j]
        other[j] = 0.0


@njit_cached(inline="always")
def _add_springs(q: np.ndarray, springs: np.ndarray, other: np.ndarray) -> None:  # pragma: no cover
    """Add the springs' torques (rows ``[joint, stiffness, rest angle]``)."""
    for s in range(springs.shape[0]):
        j = int(springs[s, 0])
        other[j] += springs[s, 1] * (q[j] - springs[s, 2])


def spring_table(joints: Sequence[int], stiffness: np.ndarray, rest: Sequence[float]) -> np.ndarray:
    """Rows ``[joint, stiffness, rest angle]`` of the springs for :func:`rigid_terms_into`."""
    table = np.zeros((len(joints), 3))
    for s, (j, k, r) in enumerate(zip(joints, stiffness, rest, strict=True)):
        table[s] = (float(j), float(k), float(r))
    return table


@njit_cached()
def tip_force_into(
    jacobian_model: np.ndarray,
    coupling: np.ndarray,
    tau_ext: np.ndarray,
    sigma_min: float,
    j: np.ndarray,
    force: np.ndarray,
) -> bool:  # pragma: no cover - compiled
    """``F`` with ``J^T F = tau_ext`` for three joints; return False (F untouched) if singular.

    ``jacobian_model`` is pinocchio's 6 x n_model frame Jacobian (translational rows first),
    ``J = jacobian_model[:3] T`` in motor coordinates. Only near a singularity (``|det J|`` at
    most ``sigma_min ||J||_F^2``, a lower bound of the smallest singular value times the
    largest squared) are the singular values computed. ``j`` (3 x 3) receives ``J``.
    """
    n_model = coupling.shape[0]
    for r in range(3):
        for c in range(3):
            s = 0.0
            for k in range(n_model):
                s += jacobian_model[r, k] * coupling[k, c]
            j[r, c] = s
    a, b, c = j[0, 0], j[0, 1], j[0, 2]
    d, e, f = j[1, 0], j[1, 1], j[1, 2]
    g, h, i = j[2, 0], j[2, 1], j[2, 2]
    c00, c01, c02 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c00 + b * c01 + c * c02
    frob = a * a + b * b + c * c + d * d + e * e + f * f + g * g + h * h + i * i
    if not abs(det) > sigma_min * frob:
        if not (math.isfinite(det) and math.isfinite(frob)):
            return False
        smallest = np.linalg.svd(j)[1][-1]
        if smallest < sigma_min or det == 0.0:
            return False
    t0, t1, t2 = tau_ext[0], tau_ext[1], tau_ext[2]
    force[0] = (c00 * t0 + c01 * t1 + c02 * t2) / det
    force[1] = ((c * h - b * i) * t0 + (a * i - c * g) * t1 + (b * g - a * h) * t2) / det
    force[2] = ((b * f - c * e) * t0 + (c * d - a * f) * t1 + (a * e - b * d) * t2) / det
    return True


# -- the step, in two halves around pinocchio -------------------------------------------------


@njit_cached()
def first_prefilter_stage(
    value: float, inner: np.ndarray, k: int, a: float, b: float, stages: int
) -> float:  # pragma: no cover - compiled
    """Return the input of the pre-filter's last stage: ``value``, or its first of two stages.

    With ``stages`` 2, ``inner[k]`` (the first stage's state) becomes ``a inner[k] + b value``
    and is returned; with 1 stage ``value`` passes as is. The streaming step and the batch loop
    (:func:`~teleop_force.estimation.batch._prefilter`) both call it.
    """
    if stages == 2:
        value = a * inner[k] + b * value
        inner[k] = value
    return value


@njit_cached(nogil=False)
def prefilter_step(
    state: np.ndarray,
    sample: np.ndarray,
    omega_v: float,
    stages: int,
    coupling: np.ndarray,
    q_model: np.ndarray,
    v_model: np.ndarray,
    q_jacobian: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Check one sample, run the pre-filter and the backward difference; write pinocchio's inputs.

    ``sample`` is ``[t, q (n), tau (n)]``; ``state`` (:func:`state_size`) holds
    ``[has previous, previous t, first t, pre-filter (2 n), L state (4 n), q (n), qd (n),
    observer state (2 n), first stage (2 n), output filter (3 n)]``. The pre-filter is
    ``stages`` (1 or 2) first-order low-passes at ``omega_v`` [rad/s] in cascade (the first
    stage's state after the observer's, so the filtered angles and torques stay where one
    stage keeps them).
    Writes ``q_model = T q_v``, ``v_model = T qd`` and ``q_jacobian = T q`` (raw angles).
    Returns a status (``STEP_*``); on an error the state is untouched.
    """
    n = coupling.shape[1]
    for k in range(1 + 2 * n):
        if not math.isfinite(sample[k]):
            return STEP_NON_FINITE
    t = sample[0]
    stage1 = state[STATE_HEAD : STATE_HEAD + 2 * n]
    q = state[STATE_HEAD + 6 * n : STATE_HEAD + 7 * n]
    qd = state[STATE_HEAD + 7 * n : STATE_HEAD + 8 * n]
    inner = state[STATE_HEAD + 10 * n : STATE_HEAD + 12 * n]
    if state[0] == 0.0:
        for k in range(2 * n):
            stage1[k] = sample[1 + k]
            inner[k] = sample[1 + k]
        for k in range(n):
            qd[k] = 0.0
        state[2] = t
    else:
        dt = t - state[1]
        if not dt > 0.0:
            return STEP_TIME_NOT_INCREASING
        a = math.exp(-omega_v * dt)
        b = 1.0 - a
        for k in range(2 * n):
            value = first_prefilter_stage(sample[1 + k], inner, k, a, b, stages)
            previous = stage1[k]
            stage1[k] = a * previous + b * value
            if k < n:
                qd[k] = (stage1[k] - previous) / dt
    for k in range(n):
        q[k] = stage1[k]
    linear_map_into(coupling, q, q_model)
    linear_map_into(coupling, qd, v_model)
    linear_map_into(coupling, sample[1 : 1 + n], q_jacobian)
    return STEP_OK


@njit_cached(nogil=False)
def finish_step(
    state: np.ndarray,
    sample: np.ndarray,
    omega: float,
    lag: int,
    observer: bool,
    omega_observer: float,
    omega_output: float,
    rigid: int,
    v_model: np.ndarray,
    mass: np.ndarray,
    coriolis: np.ndarray,
    gravity: np.ndarray,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
    tip: bool,
    jacobian_model: np.ndarray,
    jacobian_motor: np.ndarray,
    sigma_min: float,
    extra: np.ndarray,
    scratch: np.ndarray,
    out: np.ndarray,
    mode: int,
    offsets: np.ndarray,
    linear_table: np.ndarray,
    linear_parameters: np.ndarray,
    wavelet_inputs: np.ndarray,
    wavelet_table: np.ndarray,
    wavelet_runs: np.ndarray,
    wavelet_psi: np.ndarray,
    grid_ints: np.ndarray,
    grid_floats: np.ndarray,
    grid_values: np.ndarray,
    effect_codes: np.ndarray,
    effect_floats: np.ndarray,
    standstill_band_rad_s: float,
    sticking_inv_rad: float,
) -> None:  # pragma: no cover - compiled
    """Rigid body, the filter ``L``, the model's terms, ``tau_ext`` and ``F`` at one sample.

    After :func:`prefilter_step`. ``rigid`` (``RIGID_*``): whether ``mass``, ``coriolis``,
    ``gravity`` hold this sample's pinocchio terms, or ``mass`` the rows ``[M v, g - C^T v]``
    (model coordinates), or there is no rigid body (zero); ``tip``: whether
    ``jacobian_model`` holds the tip Jacobian at the raw angles and ``n == 3`` (else ``F`` is
    NaN; ``jacobian_motor``, 3 x 3, receives ``J``). ``extra`` (2 n, or empty): friction
    torque and coverage weight computed outside (a friction without term encoding, its
    standstill ramp applied). ``scratch``: 7 n + the effects' work.
    ``observer``: ``tau_ext`` is the momentum observer's residual at bandwidth
    ``omega_observer`` [rad/s] (:func:`~teleop_force.estimation.momentum_observer.
    observer_update_into`, its state ``state[STATE_HEAD + 8 n : + 10 n]``), then, if
    ``omega_output`` [rad/s] > 0, the second-order Butterworth at it (:func:`~teleop_force.
    estimation.momentum_observer.butterworth_step_into`, its state the last 3 n of
    ``state``), and ``tau_model`` is ``tau_L - tau_ext``; else ``tau_ext = tau_L -
    tau_model`` of the filtered dynamics.
    ``out`` (:func:`output_size`): ``[F, tau_ext, tau_L, tau_model, weight, singular]``.
    With ``sticking_inv_rad`` > 0, the sticking state (:func:`state_size`) ends ``state`` and
    advances with the pre-filtered angles before the model's terms.
    """
    n = coupling.shape[1]
    first = state[0] == 0.0
    t = sample[0]
    dt = t - state[1]
    tau_v = state[STATE_HEAD + n : STATE_HEAD + 2 * n]
    stage2 = state[STATE_HEAD + 2 * n : STATE_HEAD + 6 * n]
    q = state[STATE_HEAD + 6 * n : STATE_HEAD + 7 * n]
    qd = state[STATE_HEAD + 7 * n : STATE_HEAD + 8 * n]
    p_hat = state[STATE_HEAD + 8 * n : STATE_HEAD + 9 * n]
    drive = state[STATE_HEAD + 9 * n : STATE_HEAD + 10 * n]
    x_head = scratch[: 2 * n]
    load = scratch[2 * n : 3 * n]
    other = scratch[3 * n : 4 * n]
    network = scratch[4 * n : 5 * n]
    previous_tau = scratch[5 * n : 6 * n]
    work = scratch[7 * n :]
    weight = out[3 + 3 * n : 3 + 4 * n]
    if rigid == RIGID_MATRICES:
        rigid_terms_into(
            q, qd, v_model, mass, coriolis, gravity, coupling, rotor, springs,
            x_head[:n], x_head[n:],
        )  # fmt: skip
    elif rigid == RIGID_MOMENTA:
        momenta_to_motor_into(q, qd, mass, coupling, rotor, springs, x_head[:n], x_head[n:])
    else:
        for k in range(2 * n):
            x_head[k] = 0.0
    # L of [M qd, -C^T qd + N + springs]; D_L(M qd) + L(-C^T qd + N + springs) is the
    # filtered rigid-body torque, the load that found effects on ``tau<j>`` read
    a = 0.0
    b = 1.0
    if first:
        for k in range(2 * n):
            stage2[k] = x_head[k]
        for k in range(n):
            load[k] = stage2[n + k]
    else:
        a = math.exp(-omega * dt)
        b = 1.0 - a
        for k in range(2 * n):
            previous = stage2[k]
            stage2[k] = a * previous + b * x_head[k]
            if k < n:
                load[k] = (stage2[k] - previous) / dt
        for k in range(n):
            load[k] += stage2[n + k]
    sticking = state[STATE_HEAD + 15 * n :]
    if sticking_inv_rad > 0.0:
        sticking_update_into(q, linear_table[:, :n], sticking_inv_rad, sticking)
    add_model_terms(
        t - state[2], q, qd, load, other, weight, network, work,
        sticking[1 + linear_table.shape[0] :], mode, offsets, linear_table,
        linear_parameters, wavelet_inputs, wavelet_table, wavelet_runs, wavelet_psi, grid_ints,
        grid_floats, grid_values,
        effect_codes, effect_floats, standstill_band_rad_s, sticking_inv_rad,
    )  # fmt: skip
    if extra.size > 0:
        for k in range(n):
            other[k] += extra[k]
            weight[k] = extra[n + k]
    tail = stage2[2 * n :]
    tau_filtered = out[3 + n : 3 + 2 * n]
    if first:
        for k in range(n):
            tail[k] = other[k]
            tail[n + k] = tau_v[k]
            tau_filtered[k] = tau_v[k]
    else:
        for k in range(n):
            previous_tau[k] = tail[n + k]
            tail[k] = a * tail[k] + b * other[k]
            tail[n + k] = a * tail[n + k] + b * tau_v[k]
            tau_filtered[k] = tail[n + k] if lag == 0 else previous_tau[k]
    tau_ext = out[3 : 3 + n]
    tau_model = out[3 + 2 * n : 3 + 3 * n]
    if observer:
        observer_update_into(
            x_head[:n], tau_v, x_head[n:], other, dt, omega_observer, lag, first, p_hat, drive,
            tau_ext,
        )  # fmt: skip
        if omega_output > 0.0:
            butterworth_step_into(
                tau_ext, state[STATE_HEAD + 12 * n : STATE_HEAD + 15 * n], omega_output, dt, first
            )
        for k in range(n):
            tau_model[k] = tau_filtered[k] - tau_ext[k]
    else:
        for k in range(n):
            tau_model[k] = load[k] + tail[k]
            tau_ext[k] = tau_filtered[k] - tau_model[k]
    state[0] = 1.0
    state[1] = t
    out[3 + 4 * n] = 0.0
    if tip and n == 3:
        if not tip_force_into(
            jacobian_model, coupling, tau_ext, sigma_min, jacobian_motor, out[:3]
        ):
            out[3 + 4 * n] = 1.0
            for k in range(3):
                out[k] = math.nan
    else:
        for k in range(3):
            out[k] = math.nan
