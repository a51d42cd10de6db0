"""One-sample evaluation of a model's terms for the streaming estimator (compiled, numba).

At 1 kHz the estimator evaluates every term of the model on *one* sample. The terms are the
single definitions of :mod:`teleop_force.friction.terms` and
:mod:`teleop_force.identification.effect_terms`, which the batch methods call too; here they
are called once per sample from one compiled function (:func:`model_terms_into`), with the
model encoded in arrays (term tables, wavelet table, coverage grids, effect codes), so that
no Python dispatch per term remains:

* :class:`ModelTerms`: friction (Coulomb-viscous term tables, or a wavelet network blended
  with its Coulomb-viscous fallback by the coverage trust), offsets and found effects;
* :func:`rigid_terms_into`: ``T^T M T qd + rotor qd`` and ``T^T (g - C^T T qd) + springs``
  from pinocchio's model-coordinate ``M``, ``C``, ``g`` (``T``: the joint coupling);
* :func:`linear_map_into`: ``matrix @ x`` of a small matrix.

Friction or effect classes without a term encoding are evaluated by their own vectorised
methods on a one-row array, so the estimator stays correct for every model.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ModelError
from teleop_force.friction.coverage import CoverageMap
from teleop_force.friction.terms import (
    coverage_trust_into,
    linear_friction_torque_into,
    term_velocity,
    trust_blend,
    wavelet_network_torque_into,
)
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effect_terms import add_effects_torque_into
from teleop_force.identification.effects import effects_table

#: Friction modes of :func:`model_terms_into`.
FRICTION_NONE, FRICTION_LINEAR, FRICTION_NETWORK = 0, 1, 2


@njit_cached()
def model_terms_into(
    io: np.ndarray,
    n: int,
    mode: int,
    offsets: np.ndarray,
    linear_table: np.ndarray,
    linear_parameters: np.ndarray,
    wavelet_inputs: np.ndarray,
    wavelet_table: np.ndarray,
    grid_ints: np.ndarray,
    grid_floats: np.ndarray,
    grid_values: np.ndarray,
    effect_codes: np.ndarray,
    effect_floats: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Friction + offsets + found effects, and the coverage trust, at one sample.

    ``io``: ``[t, q (n), qd (n), load (n)]`` in, then ``[other (n), weight (n)]`` out, then
    scratch (:meth:`ModelTerms.io_size`). ``mode``: no friction, a Coulomb-viscous term
    table (``linear_table`` = ``[rows | reach]``, (T, 2 n)), or a wavelet table blended with
    its fallback term table by the trust of the coverage grids (``grid_ints`` with no rows:
    trust 1).
    """
    t = io[0]
    q = io[1 : 1 + n]
    qd = io[1 + n : 1 + 2 * n]
    load = io[1 + 2 * n : 1 + 3 * n]
    other = io[1 + 3 * n : 1 + 4 * n]
    weight = io[1 + 4 * n : 1 + 5 * n]
    network = io[1 + 5 * n : 1 + 6 * n]
    work = io[1 + 6 * n :]
    for j in range(n):
        other[j] = 0.0
        weight[j] = 1.0
    rows = linear_table[:, :n]
    reach = linear_table[:, n:]
    if mode == FRICTION_LINEAR:
        linear_friction_torque_into(qd, rows, reach, linear_parameters, other)
    elif mode == FRICTION_NETWORK:
        for j in range(n):
            network[j] = 0.0
        wavelet_network_torque_into(qd, wavelet_inputs, wavelet_table, network)
        linear_friction_torque_into(qd, rows, reach, linear_parameters, other)  # the fallback
        if grid_ints.shape[0] > 0:
            coverage_trust_into(qd, grid_ints, grid_floats, grid_values, weight)
        for j in range(n):
            other[j] = trust_blend(weight[j], network[j], other[j])
    for j in range(n):
        other[j] += offsets[j]
    add_effects_torque_into(effect_codes, effect_floats, t, q, qd, load, work, other)


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
        self._seen: list[np.ndarray | None] = [None] * n
        self.values = np.zeros(0)

    def refresh(self) -> None:
        """Re-read the density grids if any changed (new counts)."""
        coverage, seen = self.coverage, self._seen
        for j in range(len(seen)):
            if coverage.density_grid(j) is not seen[j]:
                break
        else:
            return
        chunks = []
        offset = 0
        for j in range(len(seen)):
            grid = coverage.density_grid(j)
            seen[j] = grid
            self.ints[j, 1] = offset
            chunks.append(np.asarray(grid, dtype=float).reshape(-1))
            offset += chunks[-1].size
        self.values = np.ascontiguousarray(np.concatenate(chunks))


_UNSET = object()
_NO_INTS = np.zeros((0, 4), dtype=np.int64)
_NO_FLOATS = np.zeros((0, 4))
_NO_VALUES = np.zeros(0)


class ModelTerms:
    """Friction, offsets and found effects of a model at one sample, in one compiled call.

    Follows later changes of the model's friction: new parameters (read live), a network's
    new structure or coefficients, a replaced fallback or coverage map, new coverage counts.
    """

    def __init__(self, model: DynamicModel) -> None:
        """Encode ``model``'s terms (ModelError: an effect outside the model's joints)."""
        self.model = model
        self.n = n = model.n_joints
        self.friction = model.friction
        table = effects_table(model.effects, n)
        self._effect_codes, self._effect_floats = table.codes, table.floats
        self.io = np.zeros(1 + 6 * n + table.work.size)
        self._out = slice(1 + 3 * n, 1 + 5 * n)
        self._network = self.friction if isinstance(self.friction, WaveletNetwork) else None
        self._linear = None if self._network is not None else _term_table(self.friction, n)
        self._fallback: Any = _UNSET  # what the tables below were built for
        self._coverage: object = _UNSET
        self._grids: _CoverageGrids | None = None
        self._fallback_table = np.zeros((0, 2 * n))

    def _refresh_network(self, network: WaveletNetwork) -> None:
        """(Re)build the tables of the network's fallback and coverage map."""
        fallback = network.fallback
        if fallback is None:
            raise ModelError("wn: blended_torque needs a fitted coupled-CV fallback model")
        table = _term_table(fallback, self.n)
        if table is None:
            raise ModelError(f"wn: fallback {fallback.kind} has no Coulomb-viscous terms")
        self._fallback, self._fallback_table = fallback, table
        coverage = network.coverage
        self._coverage = coverage
        self._grids = None if coverage is None else _CoverageGrids(coverage)

    def __call__(
        self, t: float, q: Sequence[float], qd: Sequence[float], load: Sequence[float]
    ) -> tuple[list[float], list[float]]:
        """``(friction + offsets + effects, coverage weight)`` per joint at one sample.

        ``t`` is the time since the stream's first sample, ``load`` the filtered rigid-body
        model torque (the effects' ``tau<j>``).
        """
        n = self.n
        io = self.io
        io[: 1 + 3 * n] = [t, *q, *qd, *load]
        network = self._network
        friction = self.friction
        python_friction = False
        if network is not None:
            if network.fallback is not self._fallback or network.coverage is not self._coverage:
                self._refresh_network(network)
            grids = self._grids
            if grids is not None:
                grids.refresh()
                grid_ints, grid_floats, values = grids.ints, grids.floats, grids.values
            else:
                grid_ints, grid_floats, values = _NO_INTS, _NO_FLOATS, _NO_VALUES
            inputs, wavelets = network.streaming_table()
            model_terms_into(
                io, n, FRICTION_NETWORK, self.model.offsets_nm, self._fallback_table,
                self._fallback.parameters, inputs, wavelets, grid_ints, grid_floats, values,
                self._effect_codes, self._effect_floats,
            )  # fmt: skip
        else:
            linear = self._linear
            python_friction = linear is None
            model_terms_into(
                io, n, FRICTION_NONE if python_friction else FRICTION_LINEAR,
                self.model.offsets_nm, _NO_LINEAR if linear is None else linear,
                friction.parameters, _NO_WAVELET_INPUTS, _NO_FLOATS, _NO_INTS, _NO_FLOATS,
                _NO_VALUES, self._effect_codes, self._effect_floats,
            )  # fmt: skip
        out = io[self._out].tolist()
        other, weight = out[:n], out[n:]
        if python_friction:
            row = np.asarray([qd], dtype=float)
            torque = self.model.friction_torque(row)[0].tolist()
            other = [o + f for o, f in zip(other, torque, strict=True)]
            weight = friction.coverage_weight(row)[0].tolist()
        return other, weight


_NO_LINEAR = np.zeros((0, 2))
_NO_WAVELET_INPUTS = np.zeros((0, 1), dtype=np.int64)


def _term_table(friction: object, n: int) -> np.ndarray | None:
    """``[rows | reach]`` (T, 2 n) of a Coulomb-viscous friction model; None for others."""
    term_table = getattr(friction, "term_table", None)
    if term_table is None:
        return None
    rows, reach = term_table()
    return np.ascontiguousarray(np.concatenate((rows, reach), axis=1), dtype=float)


@njit_cached()
def linear_map_into(matrix: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    """``out = matrix @ x`` over the nonzero entries of a small matrix."""
    for i in range(matrix.shape[0]):
        out[i] = term_velocity(matrix[i], x)


@njit_cached()
def rigid_terms_into(
    state: np.ndarray,
    v_model: np.ndarray,
    mass: np.ndarray,
    coriolis: np.ndarray,
    gravity: np.ndarray,
    coupling: np.ndarray,
    rotor: np.ndarray,
    springs: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Momentum and ``-C^T qd + N + springs`` in motor coordinates, at one sample.

    ``state``: ``[q (n), qd (n), momentum (n), other (n)]``, the last two written;
    ``v_model = T qd``; ``mass`` (upper triangle valid), ``coriolis``, ``gravity`` are
    pinocchio's in model coordinates, ``coupling`` is ``T`` (n_model, n), ``springs`` rows
    ``[joint, stiffness, rest angle]``. The result is ``T^T M v_model + rotor qd`` and
    ``T^T (g - C^T v_model) + springs``.
    """
    n_model, n = coupling.shape
    q = state[:n]
    qd = state[n : 2 * n]
    momentum = state[2 * n : 3 * n]
    other = state[3 * n : 4 * n]
    for j in range(n):
        momentum[j] = rotor[j] * qd[j]
        other[j] = 0.0
    for i in range(n_model):
        p = 0.0
        w = 0.0
        for j in range(n_model):
            p += (mass[i, j] if i <= j else mass[j, i]) * v_model[j]
            w += coriolis[j, i] * v_model[j]
        w = gravity[i] - w
        for j in range(n):
            t = coupling[i, j]
            if t == 1.0:
                momentum[j] += p
                other[j] += w
            elif t != 0.0:
                momentum[j] += t * p
                other[j] += t * w
    for s in range(springs.shape[0]):
        j = int(springs[s, 0])
        other[j] += springs[s, 1] * (q[j] - springs[s, 2])


def spring_table(joints: Sequence[int], stiffness: np.ndarray, rest: Sequence[float]) -> np.ndarray:
    """Rows ``[joint, stiffness, rest angle]`` of the springs for :func:`rigid_terms_into`."""
    table = np.zeros((len(joints), 3))
    for s, (j, k, r) in enumerate(zip(joints, stiffness, rest, strict=True)):
        table[s] = (float(j), float(k), float(r))
    return table
