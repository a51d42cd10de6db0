"""The whole estimator step in one compiled call: packed tables, the rigid body from the chain.

At 1 kHz a sample's cost is dominated by crossings into compiled code, not by arithmetic:
numba's dispatcher spends ~70 ns per array argument, and each pinocchio call ~1 µs. The
two-half step of :mod:`teleop_force.estimation.kernels` crosses six times per sample (the
pre-filter, four pinocchio calls, the finish with ~35 arguments). Here a sample crosses once,
with nine arguments:

* the model's constant arrays (filter gains, coupling, rotor, springs, the kinematic chain of
  :mod:`teleop_force.estimation.rigid_chain`, the friction's term table, the found effects)
  are packed into one float and one int buffer (:class:`StepTables`), with a header of
  ``(offset, shape)`` per slot in the int buffer;
* the wavelet network's tables (rebuilt by :class:`~teleop_force.estimation.kernels.
  ModelTerms` when its structure, coefficients or coverage counts change) into a second pair;
* ``M v``, ``g - C^T v`` and the tip Jacobian come from the compiled chain
  (:mod:`~teleop_force.estimation.rigid_chain`, equal to pinocchio's to rounding) instead of
  pinocchio's four calls, and enter :func:`~teleop_force.estimation.kernels.finish_step` as
  they are (``RIGID_MOMENTA``);
* the step itself is the same :func:`~teleop_force.estimation.kernels.prefilter_step` and
  :func:`~teleop_force.estimation.kernels.finish_step`, called from compiled code, so the two
  paths cannot drift apart.

:class:`StepTables` returns None for a model the fused step does not cover (no kinematic chain
encoding, a friction without term table); the estimator then runs the two halves.
"""

from __future__ import annotations

import numpy as np

from teleop_force.compiled import njit_cached, view_2d
from teleop_force.estimation.kernels import (
    RIGID_MOMENTA,
    RIGID_NONE,
    STEP_OK,
    ModelTerms,
    finish_step,
    prefilter_step,
)
from teleop_force.estimation.rigid_chain import (
    ChainTables,
    chain_kinematics_into,
    chain_momentum_into,
    chain_tip_jacobian_into,
    chain_work_size,
)
from teleop_force.packed_tables import pack, slot_1d, slot_2d, slot_3d, slot_size

# Float slots of the constant tables.
F_SCALARS, F_COUPLING, F_ROTOR, F_SPRINGS, F_OFFSETS, F_LINEAR_TABLE = 0, 1, 2, 3, 4, 5
F_EFFECT_FLOATS, F_AXIS, F_ROTATION, F_TRANSLATION, F_MASS, F_COM = 6, 7, 8, 9, 10, 11
F_INERTIA, F_GRAVITY, F_TIP_TRANSLATION = 12, 13, 14
N_FLOAT_SLOTS = 15
# Int slots of the constant tables.
I_FLAGS, I_EFFECT_CODES, I_PARENT, I_KIND, I_VELOCITY_INDEX, I_TIP_SUPPORT = 0, 1, 2, 3, 4, 5
N_INT_SLOTS = 6
# Slots of the network tables (floats, then ints).
NF_WAVELETS, NF_PSI, NF_GRID_FLOATS, NF_GRID_VALUES = 0, 1, 2, 3
N_NETWORK_FLOAT_SLOTS = 4
NI_INPUTS, NI_RUNS, NI_GRID_INTS = 0, 1, 2
N_NETWORK_INT_SLOTS = 3
# Entries of the scalar and flag slots.
(
    S_OMEGA_V, S_OMEGA, S_SIGMA_MIN, S_OMEGA_OBSERVER, S_STANDSTILL_BAND, S_OMEGA_OUTPUT,
    S_STICKING_INV,
) = range(7)  # fmt: skip
N_SCALARS = 7
G_LAG, G_RIGID, G_TIP, G_MODE, G_TIP_BODY, G_OBSERVER, G_PREFILTER_STAGES = 0, 1, 2, 3, 4, 5, 6
N_FLAGS = 7


@njit_cached(inline="always")
def _work_floats(n: int, n_model: int, n_bodies: int) -> int:  # pragma: no cover - compiled
    """Scratch of :func:`fused_step` before the found effects' work."""
    return 1 + 2 * n + 8 * n_model + 9 + chain_work_size(n_bodies) + 7 * n


def work_size(n: int, n_model: int, n_bodies: int, terms_work: int) -> int:
    """Floats of the fused step's scratch for ``n`` joints (``n_model`` model coordinates)."""
    return int(_work_floats(n, n_model, n_bodies)) + terms_work


@njit_cached(nogil=False)
def fused_step(
    state: np.ndarray,
    t_s: float,
    q_rad: np.ndarray,
    tau_nm: np.ndarray,
    floats: np.ndarray,
    ints: np.ndarray,
    network_floats: np.ndarray,
    network_ints: np.ndarray,
    linear_parameters: np.ndarray,
    work: np.ndarray,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """One sample through the whole step; returns a ``STEP_*`` code (state untouched on error).

    ``q_rad`` and ``tau_nm`` are arrays or tuples of ``n`` floats (nothing is checked but
    their length: the caller's contract). ``state`` and ``out`` as
    :func:`~teleop_force.estimation.kernels.finish_step`'s; the
    tables as packed by :class:`StepTables`; ``linear_parameters`` the friction's (or the
    network fallback's) parameters, read live; ``work`` scratch (:func:`work_size`).
    """
    scalars = slot_1d(floats, ints, F_SCALARS)
    flags = slot_1d(ints, ints, N_FLOAT_SLOTS + I_FLAGS)
    coupling = slot_2d(floats, ints, F_COUPLING)
    n_model, n = coupling.shape
    n_bodies = slot_size(ints, N_FLOAT_SLOTS + I_PARENT)
    if work.size < _work_floats(n, n_model, n_bodies) or len(q_rad) != n or len(tau_nm) != n:
        raise ValueError("fused_step: work buffer too small or wrong number of joints")
    sample = work[: 1 + 2 * n]
    sample[0] = t_s
    for k in range(n):
        sample[1 + k] = q_rad[k]
        sample[1 + n + k] = tau_nm[k]
    work = work[1 + 2 * n :]
    q_model = work[:n_model]
    v_model = work[n_model : 2 * n_model]
    q_jacobian = work[2 * n_model : 3 * n_model]
    code = prefilter_step(
        state, sample, scalars[S_OMEGA_V], flags[G_PREFILTER_STAGES], coupling, q_model, v_model,
        q_jacobian,
    )  # fmt: skip
    if code != STEP_OK:
        return code
    o = 3 * n_model
    momenta = view_2d(work, o, 2, n_model)  # [M v, g - C^T v], model coordinates
    o += 2 * n_model
    jacobian = view_2d(work, o, 3, n_model)
    o += 3 * n_model
    jacobian_motor = view_2d(work, o, 3, 3)
    o += 9
    chain_work = work[o : o + chain_work_size(n_bodies)]
    o += chain_work_size(n_bodies)
    scratch = work[o:]
    rigid = flags[G_RIGID] != 0
    rigid_mode = RIGID_MOMENTA if rigid else RIGID_NONE
    tip = flags[G_TIP] != 0
    parent = slot_1d(ints, ints, N_FLOAT_SLOTS + I_PARENT)
    kind = slot_1d(ints, ints, N_FLOAT_SLOTS + I_KIND)
    velocity_index = slot_1d(ints, ints, N_FLOAT_SLOTS + I_VELOCITY_INDEX)
    axis = slot_2d(floats, ints, F_AXIS)
    rotation = slot_3d(floats, ints, F_ROTATION)
    translation = slot_2d(floats, ints, F_TRANSLATION)
    if rigid:
        body_mass = slot_1d(floats, ints, F_MASS)
        com = slot_2d(floats, ints, F_COM)
        inertia = slot_3d(floats, ints, F_INERTIA)
        gravity_world = slot_1d(floats, ints, F_GRAVITY)
        chain_kinematics_into(
            q_model, parent, kind, axis, rotation, translation, velocity_index, chain_work
        )
        chain_momentum_into(
            v_model, parent, velocity_index, body_mass, com, inertia, gravity_world, chain_work,
            momenta[0], momenta[1],
        )  # fmt: skip
    if tip:
        chain_kinematics_into(
            q_jacobian, parent, kind, axis, rotation, translation, velocity_index, chain_work
        )
        chain_tip_jacobian_into(
            parent, velocity_index, flags[G_TIP_BODY], slot_1d(floats, ints, F_TIP_TRANSLATION),
            slot_1d(ints, ints, N_FLOAT_SLOTS + I_TIP_SUPPORT), chain_work, jacobian,
        )  # fmt: skip
    finish_step(
        state, sample, scalars[S_OMEGA], flags[G_LAG], flags[G_OBSERVER] != 0,
        scalars[S_OMEGA_OBSERVER], scalars[S_OMEGA_OUTPUT], rigid_mode, v_model, momenta,
        momenta, momenta[0], coupling,
        slot_1d(floats, ints, F_ROTOR), slot_2d(floats, ints, F_SPRINGS), tip, jacobian,
        jacobian_motor, scalars[S_SIGMA_MIN], work[:0], scratch, out, flags[G_MODE],
        slot_1d(floats, ints, F_OFFSETS), slot_2d(floats, ints, F_LINEAR_TABLE), linear_parameters,
        slot_2d(network_ints, network_ints, N_NETWORK_FLOAT_SLOTS + NI_INPUTS),
        slot_2d(network_floats, network_ints, NF_WAVELETS),
        slot_2d(network_ints, network_ints, N_NETWORK_FLOAT_SLOTS + NI_RUNS),
        slot_1d(network_floats, network_ints, NF_PSI),
        slot_2d(network_ints, network_ints, N_NETWORK_FLOAT_SLOTS + NI_GRID_INTS),
        slot_2d(network_floats, network_ints, NF_GRID_FLOATS),
        slot_1d(network_floats, network_ints, NF_GRID_VALUES),
        slot_2d(ints, ints, N_FLOAT_SLOTS + I_EFFECT_CODES),
        slot_1d(floats, ints, F_EFFECT_FLOATS), scalars[S_STANDSTILL_BAND], scalars[S_STICKING_INV],
    )  # fmt: skip
    return STEP_OK


class StepTables:
    """A model packed for :func:`fused_step`, its network tables kept current.

    Build with :meth:`create` (None when the fused step does not cover the model). The
    friction's parameters stay the live array the model holds; the network's tables are
    repacked when :class:`~teleop_force.estimation.kernels.ModelTerms` rebuilds its
    arguments (new structure, coefficients or coverage counts).
    """

    def __init__(
        self,
        terms: ModelTerms,
        floats: np.ndarray,
        ints: np.ndarray,
        n_model: int,
        n_bodies: int,
    ) -> None:
        """Wrap packed constant tables; prefer :meth:`create`."""
        self.terms = terms
        self.floats = floats
        self.ints = ints
        self.work = np.zeros(work_size(terms.n, n_model, n_bodies, terms.work.size))
        self._arguments: tuple[object, ...] | None = None
        self.network_floats = np.zeros(0)
        self.network_ints = np.zeros(0, dtype=np.int64)
        self.linear_parameters = np.zeros(0)
        self.refresh()

    @classmethod
    def create(
        cls,
        terms: ModelTerms,
        chain: ChainTables | None,
        *,
        coupling: np.ndarray,
        rotor: np.ndarray,
        springs: np.ndarray,
        omega_v: float,
        prefilter_stages: int,
        omega: float,
        omega_observer: float,
        omega_output: float,
        observer: bool,
        lag: int,
        sigma_min: float,
        tip: bool,
    ) -> StepTables | None:
        """Pack a model's constant tables; None if ``chain`` is None or the friction is Python.

        ``omega_v`` and ``prefilter_stages``: the estimator's pre-filter; ``chain`` encodes the
        equivalent rigid body (None: no rigid body, or joints the chain
        does not encode); ``tip``: whether the step computes ``F`` (three joints and a tip).
        """
        if chain is None or terms.python_friction:
            return None
        arguments = terms.arguments()
        mode, offsets, linear_table = arguments[0], arguments[1], arguments[2]
        n_model = coupling.shape[0]
        scalars = np.zeros(N_SCALARS)
        scalars[S_OMEGA_V] = omega_v
        scalars[S_OMEGA] = omega
        scalars[S_SIGMA_MIN] = sigma_min
        scalars[S_OMEGA_OBSERVER] = omega_observer
        scalars[S_OMEGA_OUTPUT] = omega_output
        scalars[S_STANDSTILL_BAND] = terms.standstill_band_rad_s
        scalars[S_STICKING_INV] = terms.sticking_inv_rad
        flags = np.zeros(N_FLAGS, dtype=np.int64)
        flags[G_LAG] = lag
        flags[G_RIGID] = 1
        flags[G_TIP] = int(tip and chain.tip_body >= 0)
        flags[G_MODE] = int(mode)
        flags[G_TIP_BODY] = max(chain.tip_body, 0)
        flags[G_OBSERVER] = int(observer)
        flags[G_PREFILTER_STAGES] = int(prefilter_stages)
        float_arrays = [
            scalars, coupling, rotor, springs, offsets, linear_table, terms.effect_floats,
            chain.axis, chain.rotation, chain.translation, chain.mass, chain.com,
            chain.inertia, chain.gravity, chain.tip_translation,
        ]  # fmt: skip
        int_arrays = [
            flags, terms.effect_codes, chain.parent, chain.kind, chain.velocity_index,
            chain.tip_support,
        ]  # fmt: skip
        floats, ints = pack(float_arrays, int_arrays)
        return cls(terms, floats, ints, n_model, chain.n_bodies)

    def refresh(self) -> None:
        """Repack the network's tables if the model's terms changed since the last call."""
        arguments = self.terms.arguments()
        if arguments is self._arguments:
            return
        self._arguments = arguments
        self.linear_parameters = np.ascontiguousarray(arguments[3], dtype=float)
        inputs, wavelets, runs, psi, grid_ints, grid_floats, values = arguments[4:11]
        self.network_floats, self.network_ints = pack(
            [wavelets, psi, grid_floats, values],
            [inputs, runs, grid_ints],
        )
        #: :func:`fused_step`'s arguments after the sample, but for ``out``.
        self.call_arguments = (
            self.floats, self.ints, self.network_floats, self.network_ints,
            self.linear_parameters, self.work,
        )  # fmt: skip
