"""The rigid-body regressor in motor coordinates and the base parameters found by QR.

Full parameters, in order: 10 per link (pinocchio's ``m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz,
Izz``), one rotor inertia per motor, one stiffness per spring. Three regressors share them:

- :meth:`RigidBodyRegressor.standard`: ``Y(q, qd, qdd) pi = M qdd + C qd + N + tau_spring``;
- :meth:`RigidBodyRegressor.momentum`: ``Y_p(q, qd) pi = M(q) qd``, the generalized momentum;
- :meth:`RigidBodyRegressor.coriolis_gravity`: ``Y_w(q, qd) pi = -C^T qd + N + tau_spring``.

Every regressor is pinocchio's in model coordinates mapped through the coupling:
``Y_motor(q, qd, qdd) = T^T Y_model(T q, T qd, T qdd)``, for a square ``T`` and for a closed
chain written as a tree with extra joints (``T`` is then ``n_model x n``).

Since ``d/dt (M qd) = M qdd + Mdot qd`` and ``Mdot = C + C^T``, the torque is
``d/dt p - C^T qd + N + tau_spring``: the momentum form needs no acceleration once filtered.
``Mdot qd`` is the directional derivative of ``M(q) qd`` along ``qd`` (central difference).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, cast

import numpy as np
import pinocchio as pin
from msgspec import Meta, Struct

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.robots.description import LINK_PARAMETER_NAMES, RobotDescription
from teleop_force.schema import Finite

_DIRECTIONAL_STEP = 1e-5
#: A parameter index in a model file.
ParameterIndex = Annotated[int, Meta(ge=0, lt=2**31)]


def full_parameter_names(description: RobotDescription) -> list[str]:
    """Names of the full parameter vector of ``description``."""
    names: list[str] = []
    if description.model is not None:
        for j in range(1, description.model.njoints):
            names += [f"{p}_{j}" for p in LINK_PARAMETER_NAMES]
    names += [f"Ia_{i + 1}" for i in range(description.n_joints)]
    names += [f"k_{s.joint + 1}" for s in description.springs]
    return names


def full_parameters(
    description: RobotDescription, spring_stiffness: np.ndarray | Sequence[float]
) -> np.ndarray:
    """Full parameter vector of a description (its model's inertias) and given stiffnesses."""
    return np.concatenate(
        (
            description.link_parameters(),
            description.rotor_inertia_kgm2,
            np.asarray(spring_stiffness, dtype=float).reshape(-1),
        )
    )


@dataclass(frozen=True, eq=False)
class BaseParameters:
    """The identifiable combinations of the full parameters, ``beta = pi_B + K pi_D``.

    Attributes:
        full_names: Names of the full parameters.
        independent: Indices of the full parameters kept as base parameters (sorted).
        dependent: Indices of the others.
        dependency: ``K``, with ``Y[:, dependent] = Y[:, independent] @ K``.

    """

    full_names: tuple[str, ...]
    independent: np.ndarray
    dependent: np.ndarray
    dependency: np.ndarray

    def __post_init__(self) -> None:
        n_full = len(self.full_names)
        if self.independent.ndim != 1 or self.dependent.ndim != 1:
            raise ModelError("base parameters: index sets must be flat")
        if self.independent.size + self.dependent.size != n_full:
            raise ModelError("base parameters: index sets do not partition the parameters")
        every = np.sort(np.concatenate((self.independent, self.dependent)))
        if not np.array_equal(every, np.arange(n_full)):
            raise ModelError(
                f"base parameters: independent and dependent indices must be 0..{n_full - 1}, "
                "each once"
            )
        if self.dependency.shape != (self.independent.size, self.dependent.size):
            raise ModelError("base parameters: dependency matrix has the wrong shape")

    @property
    def count(self) -> int:
        """Number of base parameters."""
        return int(self.independent.size)

    def names(self) -> list[str]:
        """Each base parameter as an expression of full parameters, e.g. ``Iyy_1 + Ia_1``."""
        out = []
        for row, i in enumerate(self.independent):
            terms = [self.full_names[i]]
            for col, d in enumerate(self.dependent):
                k = self.dependency[row, col]
                if abs(k) > 1e-9:
                    coef = "" if abs(k - 1) < 1e-9 else f"{k:.4g}*"
                    terms.append(f"{coef}{self.full_names[d]}")
            out.append(" + ".join(terms).replace("+ -", "- "))
        return out

    def project(self, full: np.ndarray) -> np.ndarray:
        """Project a full parameter vector onto the base parameters."""
        return full[self.independent] + self.dependency @ full[self.dependent]

    def representative(self, base: np.ndarray, nominal_full: np.ndarray) -> np.ndarray:
        """Return a full parameter vector with these base parameters.

        It equals ``nominal_full`` on the dependent parameters (so masses stay non-zero).
        """
        full = np.array(nominal_full, dtype=float)
        full[self.independent] = base - self.dependency @ full[self.dependent]
        return full

    def representative_with_masses(
        self,
        base: np.ndarray,
        nominal_full: np.ndarray,
        mass_indices: Sequence[int],
        min_mass: float = 1e-2,
    ) -> np.ndarray:
        """Return a full parameter vector with these base parameters and every mass >= ``min_mass``.

        :meth:`representative` keeps the dependent parameters nominal, which can leave a mass
        that is an independent parameter negative (the MTM's elbow link: -0.74 kg). Such a
        vector has the right base parameters, but pinocchio's composite inertias clamp a
        negative subtree mass to machine epsilon and divide by it (``crba`` returned 1e29).
        So the dependent parameters are moved, as little as possible (relative to their
        nominal size), until every mass is at least ``min_mass``; the base parameters, and
        so every torque, are unchanged. Raises ModelError when no choice can do it.
        """
        full = self.representative(base, nominal_full)
        masses = np.asarray(mass_indices, dtype=int)
        if np.all(full[masses] >= min_mass):
            return full
        from scipy.optimize import LinearConstraint, minimize

        position = {int(i): k for k, i in enumerate(self.independent)}
        dep_position = {int(d): k for k, d in enumerate(self.dependent)}
        rows, bounds = [], []
        for i in masses:
            row = np.zeros(self.dependent.size)
            if int(i) in dep_position:  # the mass itself is free
                row[dep_position[int(i)]] = 1.0
                rows.append(row)
                bounds.append(min_mass)
            else:  # independent: base - K pi_D >= min_mass, i.e. -K pi_D >= min_mass - base
                k = position[int(i)]
                rows.append(-self.dependency[k])
                bounds.append(min_mass - base[k])
        nominal_dep = np.asarray(nominal_full, dtype=float)[self.dependent]
        scale = np.abs(nominal_dep) + 1e-2
        constraint = LinearConstraint(np.array(rows) * scale[None, :], np.array(bounds), np.inf)
        result = minimize(
            lambda z: float(np.sum((z - nominal_dep / scale) ** 2)),
            nominal_dep / scale,
            jac=lambda z: 2.0 * (z - nominal_dep / scale),
            constraints=[constraint],
            method="SLSQP",
        )
        dependent = result.x * scale
        full = np.asarray(nominal_full, dtype=float).copy()
        full[self.dependent] = dependent
        full[self.independent] = base - self.dependency @ dependent
        if not np.all(full[masses] >= min_mass * (1.0 - 1e-6)):
            low = [self.full_names[i] for i in masses if full[i] < min_mass * (1.0 - 1e-6)]
            raise ModelError(
                f"no equivalent rigid body with positive masses: {', '.join(low)} stay below"
                f" {min_mass} kg whatever the unidentifiable parameters (the identified base"
                " parameters are not physical)"
            )
        return full

    def to_dict(self) -> dict[str, object]:
        """Serialise."""
        return {
            "full_names": list(self.full_names),
            "independent": self.independent.tolist(),
            "dependent": self.dependent.tolist(),
            "dependency": self.dependency.tolist(),
        }


class BaseParametersEntry(Struct):
    """``base``: full parameter names, the independent / dependent split and ``K``."""

    full_names: list[str]
    independent: list[ParameterIndex]
    dependent: list[ParameterIndex]
    dependency: list[list[Finite]]

    def __post_init__(self) -> None:
        size = len(self.full_names)
        for name, indices in (("independent", self.independent), ("dependent", self.dependent)):
            if any(i >= size for i in indices):
                raise ModelFileError(f"index {max(indices)} outside 0..{size - 1}", column=name)
        rows, cols = len(self.independent), len(self.dependent)
        if len(self.dependency) != rows or any(len(row) != cols for row in self.dependency):
            raise ModelFileError(f"expected {rows} rows of {cols} numbers", column="dependency")
        self.parameters()  # BaseParameters' own checks (each index once)

    def parameters(self) -> BaseParameters:
        """Build the :class:`BaseParameters` (ModelFileError if an index repeats or lacks)."""
        rows, cols = len(self.independent), len(self.dependent)
        try:
            return BaseParameters(
                tuple(self.full_names),
                np.array(self.independent, dtype=np.int64),
                np.array(self.dependent, dtype=np.int64),
                np.array(self.dependency, dtype=float).reshape(rows, cols),
            )
        except ModelError as exc:
            raise ModelFileError(str(exc), column="independent") from None


class RigidBodyRegressor:
    """Regressors of a robot description in motor coordinates (one instance per thread)."""

    def __init__(self, description: RobotDescription) -> None:
        """Prepare pinocchio models with and without gravity."""
        if description.model is None:
            raise ModelError(f"{description.name}: no rigid-body model for a regressor")
        self.description = description
        self.n = description.n_joints
        self.coupling = description.coupling
        self.model = description.model
        self.data = self.model.createData()
        self.model_no_gravity = self.model.copy()
        self.model_no_gravity.gravity = pin.Motion.Zero()
        self.data_no_gravity = self.model_no_gravity.createData()
        self.n_link_parameters = 10 * description.n_links
        self.n_parameters = self.n_link_parameters + self.n + len(description.springs)
        self._spring_joints = [s.joint for s in description.springs]
        self._spring_rest = [s.rest_angle_rad for s in description.springs]

    def _links(
        self, model: pin.Model, data: pin.Data, q: np.ndarray, v: np.ndarray, a: np.ndarray
    ) -> np.ndarray:
        t = self.coupling
        y = pin.computeJointTorqueRegressor(model, data, t @ q, t @ v, t @ a)
        return t.T @ y

    def _assemble(
        self, links: np.ndarray, rotor_diag: np.ndarray, q: np.ndarray | None
    ) -> np.ndarray:
        y = np.zeros((self.n, self.n_parameters))
        y[:, : self.n_link_parameters] = links
        y[:, self.n_link_parameters : self.n_link_parameters + self.n] = np.diag(rotor_diag)
        if q is not None:
            for col, (j, rest) in enumerate(
                zip(self._spring_joints, self._spring_rest, strict=True)
            ):
                y[j, self.n_link_parameters + self.n + col] = q[j] - rest
        return y

    def standard(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """``Y(q, qd, qdd)``: torque = ``Y @ pi`` (n x P)."""
        return self._assemble(self._links(self.model, self.data, q, qd, qdd), qdd, q)

    def momentum(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``Y_p(q, qd)``: ``M(q) qd = Y_p @ pi`` (n x P)."""
        zero = np.zeros(self.n)
        links = self._links(self.model_no_gravity, self.data_no_gravity, q, zero, qd)
        return self._assemble(links, qd, None)

    def coriolis_gravity(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``Y_w(q, qd)``: ``-C^T qd + N + tau_spring = Y_w @ pi`` (n x P)."""
        zero = np.zeros(self.n)
        speed = float(np.linalg.norm(qd))
        c_qd_plus_gravity = self._links(self.model, self.data, q, qd, zero)
        if speed > 0.0:
            h = _DIRECTIONAL_STEP / speed
            ahead = self._links(self.model_no_gravity, self.data_no_gravity, q + h * qd, zero, qd)
            behind = self._links(self.model_no_gravity, self.data_no_gravity, q - h * qd, zero, qd)
            mdot_qd = (ahead - behind) / (2.0 * h)
            links = c_qd_plus_gravity - mdot_qd
        else:
            links = c_qd_plus_gravity
        return self._assemble(links, zero, q)

    def momentum_form_batch(
        self, q: np.ndarray, qd: np.ndarray, columns: np.ndarray | None = None, chunk: int = 4096
    ) -> tuple[np.ndarray, np.ndarray]:
        """``Y_p`` and ``Y_w`` of every sample (``(N, n, P)`` each, or ``[..., columns]``).

        The same numbers as :meth:`momentum` and :meth:`coriolis_gravity` row by row (up to
        rounding), with only the four pinocchio regressor calls left in the per-sample loop:
        the couplings, the central difference and the rotor and spring columns are applied
        to ``chunk`` samples at once.
        """
        q = np.asarray(q, dtype=float)
        qd = np.asarray(qd, dtype=float)
        n_samples, n = q.shape
        n_model = self.model.nv
        cols = np.arange(self.n_parameters) if columns is None else np.asarray(columns)
        y_p = np.empty((n_samples, n, cols.size))
        y_w = np.empty_like(y_p)
        t = self.coupling
        nl = self.n_link_parameters
        link_cols = cols[cols < nl]
        link_pos = np.flatnonzero(cols < nl)
        rotor_pos = np.flatnonzero((cols >= nl) & (cols < nl + n))
        rotor_joint = cols[rotor_pos] - nl
        spring_pos = np.flatnonzero(cols >= nl + n)
        spring_index = cols[spring_pos] - nl - n
        regressor = pin.computeJointTorqueRegressor
        model, data = self.model, self.data
        model_ng, data_ng = self.model_no_gravity, self.data_no_gravity
        for start in range(0, n_samples, chunk):
            stop = min(start + chunk, n_samples)
            qc, qdc = q[start:stop], qd[start:stop]
            m = stop - start
            speed = np.linalg.norm(qdc, axis=1)
            moving = speed > 0.0
            h = np.where(moving, _DIRECTIONAL_STEP / np.where(moving, speed, 1.0), 0.0)
            qm = qc @ t.T
            vm = qdc @ t.T
            ahead = (qc + h[:, None] * qdc) @ t.T
            behind = (qc - h[:, None] * qdc) @ t.T
            zero = np.zeros(n_model)
            raw = np.empty((4, m * n_model, nl))
            qm_rows, vm_rows = list(qm), list(vm)
            # at rest (h = 0) ahead == behind: the difference is exactly 0
            for out, mdl, dat, positions, velocity, acceleration in (
                (raw[0], model_ng, data_ng, qm_rows, None, vm_rows),
                (raw[1], model, data, qm_rows, vm_rows, None),
                (raw[2], model_ng, data_ng, list(ahead), None, vm_rows),
                (raw[3], model_ng, data_ng, list(behind), None, vm_rows),
            ):
                if velocity is None:
                    # the rows without velocity carry the acceleration
                    pairs = zip(positions, cast(list[np.ndarray], acceleration), strict=True)
                    rows = [regressor(mdl, dat, a, zero, b) for a, b in pairs]
                else:
                    pairs = zip(positions, velocity, strict=True)
                    rows = [regressor(mdl, dat, a, b, zero) for a, b in pairs]
                np.concatenate(rows, out=out)
            raw = raw.reshape(4, m, n_model, nl)
            links = np.einsum("ij,bkjp->bkip", t.T, raw)
            mdot = (links[2] - links[3]) / np.where(moving, 2.0 * h, 1.0)[:, None, None]
            out_p = y_p[start:stop]
            out_w = y_w[start:stop]
            out_p[:] = 0.0
            out_w[:] = 0.0
            out_p[:, :, link_pos] = links[0][:, :, link_cols]
            out_w[:, :, link_pos] = (links[1] - mdot)[:, :, link_cols]
            for pos, j in zip(rotor_pos, rotor_joint, strict=True):
                out_p[:, j, pos] = qdc[:, j]
            for pos, i in zip(spring_pos, spring_index, strict=True):
                j = self._spring_joints[i]
                out_w[:, j, pos] = qc[:, j] - self._spring_rest[i]
        return y_p, y_w

    def find_base_parameters(self, n_states: int = 200, seed: int = 0) -> BaseParameters:
        """Find the base parameters numerically: QR with pivoting of ``Y`` on random states."""
        import scipy.linalg  # lazy: only identification needs it, not estimation

        rng = np.random.default_rng(seed)
        desc = self.description
        rows = []
        for _ in range(n_states):
            q = rng.uniform(desc.q_min_rad, desc.q_max_rad)
            rows.append(self.standard(q, rng.normal(size=self.n), rng.normal(size=self.n)))
        w = np.vstack(rows)
        scale = np.linalg.norm(w, axis=0)
        # Columns that are round-off noise (parameters absent from the dynamics) are zero.
        null = scale <= 1e-9 * scale.max()
        w[:, null] = 0.0
        scale[null] = 1.0
        _, r, perm = scipy.linalg.qr(w / scale, mode="economic", pivoting=True)
        diag = np.abs(np.diag(r))
        rank = int(np.sum(diag > 1e-8 * diag[0]))
        independent = np.sort(perm[:rank])
        dependent = np.sort(perm[rank:])
        if dependent.size:
            k, *_ = np.linalg.lstsq(w[:, independent], w[:, dependent], rcond=None)
        else:
            k = np.zeros((rank, 0))
        k[np.abs(k) < 1e-10] = 0.0
        return BaseParameters(tuple(full_parameter_names(desc)), independent, dependent, k)
