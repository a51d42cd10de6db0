"""The wavelet-network (WN) friction model of the paper, Section III (eqs. 4-6, Table IV).

Joint ``j``'s friction depends on the velocities ``x = qd[S_j]`` of its input set ``S_j``
(``d_j = len(S_j)``) and is a finite expansion (eq. 6)::

    tau_f,j(x) = sum_k c_k psi_{m_k, n_k}(x)
    psi_{m,n}(x) = a0^(-d m / 2) psi(a0^(-m) x - n b0),   psi(x) = (1 - |x|^2) exp(-|x|^2 / 2)

with ``a0 = 2``, ``b0 = 1`` (the Mexican hat frame of the paper). The wavelet ``(m, n)`` is
centred at ``a0^m n b0`` with width ``a0^m``; it narrows as ``m`` decreases.

Pool and active set (Section III-D):

* The *pool* ``K_j`` holds every ``(m, n)`` with ``m_min <= m <= m_max`` and a centre inside
  the velocity region ``X_r``, plus **one ring of centres just outside** ``X_r`` on every
  dilation (``edge_ring=True``), so the edges of ``X_r`` are covered by wavelets centred on
  both sides. Each dilation is a full rectangular grid of ``n``; the pool of all joints is
  stored as one concatenated array (:class:`WaveletPool`), joint by joint, coarse to fine.
* Only the *active* wavelets take part in the model. :meth:`FrictionModel.parameter_counts`,
  :attr:`WaveletNetwork.parameters`, :meth:`WaveletNetwork.basis` and
  :meth:`WaveletNetwork.parameter_names` all range over the active set, in pool order; a
  structure change (adaptation, batch fit) therefore changes the counts and the meaning of
  parameter positions. Inactive pool wavelets always have coefficient 0.
* Initially ``2^d_j`` *seed* wavelets are active: on the coarsest dilation ``m_max``, the
  centre nearest the origin in every open orthant (footnote 1: one per quadrant for d = 2).
* Neighbours of ``(m, n)`` in ``Z^(1+d)`` (used for inclusion): the pool wavelets on the
  dilations ``m' in {m - 1, m, m + 1}`` whose index ``n'`` differs by at most 1 in every
  component from ``n`` *rescaled* to the grid of ``m'``, i.e. ``|n' - a0^(m-m') n|_inf <= 1``:
  the 3^d - 1 same-dilation neighbours, the 3^d finer wavelets around ``(m, n)``'s centre, and
  the 3^d (``n`` even) or 2^d (``n`` odd) coarser wavelets nearest to it.

The model can also hold a fitted :class:`CoupledCoulombViscous` ``fallback`` and a
:class:`CoverageMap`; :meth:`WaveletNetwork.blended_torque` combines the two by the coverage
trust ``w``:

* ``on_fallback=False`` (the paper's network, the whole friction): ``w WN + (1 - w) CV``, the
  WN only where it was trained, the coupled CV model elsewhere;
* ``on_fallback=True`` (the identified Omni's default): ``CV + w WN``, the network trained on
  what the coupled CV leaves. The CV keeps the Coulomb step at zero speed, which the smooth
  wavelets can only round off, and the network adds the coupled remainder where it was
  trained.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import product
from typing import Annotated, Any, ClassVar, overload

import numpy as np
from msgspec import Meta, Struct

from teleop_force.errors import ConfigurationError, ModelError, ModelFileError
from teleop_force.friction.base import (
    FILE_ERRORS,
    FrictionModel,
    JointCount,
    JointIndex,
    file_error,
)
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.coverage import CoverageMap
from teleop_force.friction.kinds import wn_structure_name
from teleop_force.friction.terms import (
    mexican_hat_values,
    pool_wavelets,
    trust_blend_values,
    wavelet_block,
    wavelet_network_torque_into,
)
from teleop_force.schema import Finite, built_by, read_entry

A0_DEFAULT = 2.0
B0_DEFAULT = 1.0
#: Samples per chunk when evaluating a batch (keeps every temporary near the CPU caches).
_EVAL_CHUNK_ELEMENTS = 160_000
#: Bounds of a pool (the paper's Omni pool has ~13 000 wavelets over 6 dilations): a bad
#: spec or model file is refused before it can allocate gigabytes or loop for hours.
MAX_POOL_SIZE = 1_000_000
MAX_DILATIONS = 64
MAX_INPUTS = 8
#: A wavelet's dilation bound: the pool's own limits refuse what is too large to build.
Dilation = Annotated[int, Meta(ge=-1000, le=1000)]
#: A wavelet's dilation or translation in an ``active`` row (exact in a float64).
WaveletIndex = Annotated[int, Meta(ge=-(2**52), le=2**52)]


def mexican_hat(x: np.ndarray) -> np.ndarray:
    """Mother wavelet ``psi(x) = (1 - |x|^2) exp(-|x|^2 / 2)``, norm over the last axis.

    Evaluated by :func:`~teleop_force.friction.terms.mexican_hat_r2`, the one definition.
    """
    x = np.asarray(x, dtype=float)
    r2 = np.sum(x * x, axis=-1)
    return mexican_hat_values(np.ascontiguousarray(r2).reshape(-1)).reshape(r2.shape)


@overload
def wavelet_amplitude(a0: float, d: int, m: int) -> float: ...
@overload
def wavelet_amplitude(a0: float, d: np.ndarray, m: np.ndarray) -> np.ndarray: ...
def wavelet_amplitude(a0: float, d: int | np.ndarray, m: int | np.ndarray) -> float | np.ndarray:
    """Return the amplitude ``a0^(-d m / 2)`` of a wavelet of dilation ``m`` on ``d`` inputs.

    Of ints, or elementwise of arrays (the pool's ``amplitude``): the one definition.
    """
    return a0 ** (-d * m / 2.0)


def wavelet(
    x: np.ndarray, m: int, n: Sequence[int], a0: float = A0_DEFAULT, b0: float = B0_DEFAULT
) -> np.ndarray:
    """Naive ``psi_{m,n}(x) = a0^(-d m/2) psi(a0^(-m) x - n b0)`` at points ``x`` (..., d)."""
    n_arr = np.asarray(n, dtype=float).reshape(-1)
    x = np.asarray(x, dtype=float)
    d = n_arr.size
    return wavelet_amplitude(a0, d, m) * mexican_hat(a0 ** (-m) * x - n_arr * b0)


def psi_block(
    x: np.ndarray,
    centre_scaled: np.ndarray,
    inv_scale: np.ndarray,
    amplitude: np.ndarray,
) -> np.ndarray:
    """Wavelets of one joint: ``x`` (N, d) -> (N, P) (compiled, :func:`wavelet_block`).

    ``centre_scaled`` (P, d) is ``centre / scale``, ``inv_scale`` (P,) is ``a0^-m`` and
    ``amplitude`` (P,) is ``a0^(-d m/2)``.
    """
    return wavelet_block(
        np.ascontiguousarray(x, dtype=float),
        np.ascontiguousarray(centre_scaled, dtype=float),
        np.ascontiguousarray(inv_scale, dtype=float),
        np.ascontiguousarray(amplitude, dtype=float),
    )


@dataclass(frozen=True)
class WaveletJointSpec:
    """One joint's network: inputs, velocity region ``X_r``, dilations, thresholds.

    Attributes:
        inputs: Motor-joint indices whose velocities the friction depends on (``S_j``).
        x_min_rad_s, x_max_rad_s: Velocity region ``X_r``, one bound per input [rad/s].
        m_min, m_max: Dilation range (finest, coarsest), e.g. -5..0 (Table IV).
        mu: Inclusion threshold on ``|c|`` (neighbours join when ``|c| > mu``).
        theta: Exclusion threshold (a wavelet leaves when ``|c| < theta`` and decreasing);
            the paper takes ``theta > mu``, which is allowed but not required.

    """

    inputs: tuple[int, ...]
    x_min_rad_s: tuple[float, ...]
    x_max_rad_s: tuple[float, ...]
    m_min: int
    m_max: int
    mu: float
    theta: float

    def __post_init__(self) -> None:
        inputs = tuple(int(i) for i in self.inputs)
        lo = tuple(float(v) for v in np.atleast_1d(self.x_min_rad_s))
        hi = tuple(float(v) for v in np.atleast_1d(self.x_max_rad_s))
        if not inputs or len(set(inputs)) != len(inputs) or min(inputs) < 0:
            raise ConfigurationError(f"bad wavelet input set {self.inputs}")
        if len(lo) != len(inputs) or len(hi) != len(inputs):
            raise ConfigurationError("x_min_rad_s / x_max_rad_s need one bound per input")
        bounds = zip(lo, hi, strict=True)
        if not all(math.isfinite(a) and math.isfinite(b) and a < b for a, b in bounds):
            raise ConfigurationError(f"velocity region needs finite min < max, got {lo}, {hi}")
        if int(self.m_min) != self.m_min or int(self.m_max) != self.m_max:
            raise ConfigurationError("dilations must be integers")
        if self.m_min > self.m_max:
            raise ConfigurationError(f"m_min {self.m_min} > m_max {self.m_max}")
        if not (0.0 < self.mu < math.inf and 0.0 < self.theta < math.inf):
            raise ConfigurationError(
                f"thresholds must be finite and > 0, got mu={self.mu}, theta={self.theta}"
            )
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "x_min_rad_s", lo)
        object.__setattr__(self, "x_max_rad_s", hi)
        object.__setattr__(self, "m_min", int(self.m_min))
        object.__setattr__(self, "m_max", int(self.m_max))
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "theta", float(self.theta))

    @property
    def d(self) -> int:
        """Number of inputs ``d_j``."""
        return len(self.inputs)

    def to_dict(self) -> dict[str, Any]:
        """Serialise to JSON-compatible values."""
        return {
            "inputs": list(self.inputs),
            "x_min_rad_s": list(self.x_min_rad_s),
            "x_max_rad_s": list(self.x_max_rad_s),
            "m_min": self.m_min,
            "m_max": self.m_max,
            "mu": self.mu,
            "theta": self.theta,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WaveletJointSpec:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        return read_entry(data, WaveletJointSpecEntry).spec()


class WaveletJointSpecEntry(Struct):
    """One joint network's inputs, velocity region, dilations and thresholds."""

    inputs: list[JointIndex]
    x_min_rad_s: list[Finite]
    x_max_rad_s: list[Finite]
    m_min: Dilation
    m_max: Dilation
    mu: Finite
    theta: Finite

    def __post_init__(self) -> None:
        self.spec()  # WaveletJointSpec's own checks, named after this entry

    def spec(self) -> WaveletJointSpec:
        """Build the joint's :class:`WaveletJointSpec` (ModelFileError if inconsistent)."""
        try:
            return WaveletJointSpec(
                tuple(self.inputs), tuple(self.x_min_rad_s), tuple(self.x_max_rad_s),
                self.m_min, self.m_max, self.mu, self.theta,
            )  # fmt: skip
        except ConfigurationError as exc:
            raise ModelFileError(str(exc)) from None


class WaveletJointEntry(WaveletJointSpecEntry):
    """A joint network: its spec, active wavelets as ``[m, n1..nd]`` rows, coefficients."""

    active: list[list[WaveletIndex]]
    coefficients: list[Finite]


def omni_wavelet_specs(
    qd1_limit_rad_s: float = 3.0, qd23_limit_rad_s: float = 3.0
) -> tuple[WaveletJointSpec, ...]:
    """Return the paper's Omni networks (Table IV) over ``|qd1| <= v1``, ``|qd2|, |qd3| <= v23``.

    Joint 1 depends on ``qd1`` (dilations -5..0, mu 4e-6, theta 5e-6); joints 2 and 3 on
    ``(qd2, qd3)`` (dilations -4..0, mu 5e-5, theta 6e-5).
    """
    v1, v23 = float(qd1_limit_rad_s), float(qd23_limit_rad_s)
    return (
        WaveletJointSpec((0,), (-v1,), (v1,), -5, 0, 4.0e-6, 5.0e-6),
        WaveletJointSpec((1, 2), (-v23, -v23), (v23, v23), -4, 0, 5.0e-5, 6.0e-5),
        WaveletJointSpec((1, 2), (-v23, -v23), (v23, v23), -4, 0, 5.0e-5, 6.0e-5),
    )


@dataclass(frozen=True)
class _Block:
    """One dilation of one joint's pool: a rectangular grid of ``n``."""

    offset: int
    n_lo: np.ndarray
    shape: tuple[int, ...]

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))


class WaveletPool:
    """Geometry of every joint's wavelet pool, concatenated in one global index.

    Arrays over the global pool (``size`` wavelets, ``dmax`` = largest input count, unused
    input columns padded): ``joint``, ``m``, ``n`` (size, dmax), ``centre`` (size, dmax)
    [rad/s], ``inv_scale`` = ``a0^-m``, ``centre_scaled`` = ``centre * inv_scale``,
    ``amplitude`` = ``a0^(-d m/2)`` and ``input_index`` (size, dmax): the velocity each input
    column reads, ``n_inputs`` (an always-zero dummy velocity) for padding.
    """

    def __init__(
        self,
        specs: Sequence[WaveletJointSpec],
        n_inputs: int,
        a0: float = A0_DEFAULT,
        b0: float = B0_DEFAULT,
        edge_ring: bool = True,
    ) -> None:
        """Build the pools of all joints."""
        if not 1.0 < a0 < math.inf or not 0.0 < b0 < math.inf:
            raise ConfigurationError(f"need finite a0 > 1 and b0 > 0, got a0={a0}, b0={b0}")
        self.specs = tuple(specs)
        self.n_inputs = int(n_inputs)
        self.a0 = float(a0)
        self.b0 = float(b0)
        self.edge_ring = bool(edge_ring)
        if not self.specs:
            raise ConfigurationError("a wavelet pool needs at least one joint")
        for spec in self.specs:
            if max(spec.inputs) >= self.n_inputs:
                raise ConfigurationError(f"wavelet input {max(spec.inputs)} >= {self.n_inputs}")
        self._check_size()
        self.dmax = max(spec.d for spec in self.specs)
        ring = 1 if self.edge_ring else 0
        blocks: list[dict[int, _Block]] = []
        rows: list[tuple[np.ndarray, ...]] = []
        offset = 0
        offsets = [0]
        for j, spec in enumerate(self.specs):
            lo = np.asarray(spec.x_min_rad_s)
            hi = np.asarray(spec.x_max_rad_s)
            joint_blocks: dict[int, _Block] = {}
            for m in range(spec.m_max, spec.m_min - 1, -1):
                step = self.a0**m * self.b0
                n_lo = np.ceil(lo / step - 1e-9).astype(np.int64) - ring
                n_hi = np.floor(hi / step + 1e-9).astype(np.int64) + ring
                shape = tuple(int(v) for v in n_hi - n_lo + 1)
                block = _Block(offset, n_lo, shape)
                joint_blocks[m] = block
                grid = np.indices(shape).reshape(spec.d, -1).T + n_lo
                n_pad = np.zeros((grid.shape[0], self.dmax), dtype=np.int64)
                n_pad[:, : spec.d] = grid
                rows.append((np.full(grid.shape[0], j), np.full(grid.shape[0], m), n_pad))
                offset += block.size
            blocks.append(joint_blocks)
            offsets.append(offset)
        self._blocks = tuple(blocks)
        self.joint_offsets = np.asarray(offsets, dtype=np.int64)
        self.joint = np.concatenate([r[0] for r in rows]).astype(np.int64)
        self.m = np.concatenate([r[1] for r in rows]).astype(np.int64)
        self.n = np.concatenate([r[2] for r in rows], axis=0)
        self.d = np.asarray([spec.d for spec in self.specs], dtype=np.int64)[self.joint]
        scale = self.a0 ** self.m.astype(float)
        self.inv_scale = 1.0 / scale
        self.amplitude = wavelet_amplitude(self.a0, self.d, self.m)
        real = np.arange(self.dmax)[None, :] < self.d[:, None]
        self.centre = np.where(real, self.n * (scale * self.b0)[:, None], 0.0)
        self.centre_scaled = self.centre * self.inv_scale[:, None]
        self.input_index = np.full((self.size, self.dmax), self.n_inputs, dtype=np.int64)
        for j, spec in enumerate(self.specs):
            sl = self.joint_slice(j)
            self.input_index[sl, : spec.d] = spec.inputs
        self.seeds = np.concatenate([self._seeds(j) for j in range(len(self.specs))])
        for name in (
            "joint", "m", "n", "d", "inv_scale", "amplitude", "centre", "centre_scaled",
            "input_index", "seeds", "joint_offsets",
        ):  # fmt: skip
            getattr(self, name).flags.writeable = False

    def _check_size(self) -> None:
        """Refuse pools beyond MAX_POOL_SIZE / MAX_DILATIONS / MAX_INPUTS before building."""
        ring = 1 if self.edge_ring else 0
        total = 0.0
        for j, spec in enumerate(self.specs):
            if spec.d > MAX_INPUTS:
                raise ConfigurationError(f"joint {j + 1}: {spec.d} inputs (at most {MAX_INPUTS})")
            if spec.m_max - spec.m_min + 1 > MAX_DILATIONS:
                raise ConfigurationError(
                    f"joint {j + 1}: dilations {spec.m_min}..{spec.m_max} (at most {MAX_DILATIONS})"
                )
            lo = np.asarray(spec.x_min_rad_s)
            hi = np.asarray(spec.x_max_rad_s)
            for m in range(spec.m_max, spec.m_min - 1, -1):
                try:
                    step = self.a0**m * self.b0
                except OverflowError:
                    step = math.inf
                with np.errstate(all="ignore"):
                    n_lo, n_hi = lo / step, hi / step
                    ok = 0.0 < step < math.inf and np.all(np.abs(np.r_[n_lo, n_hi]) < 2.0**52)
                    per_axis = np.floor(n_hi + 1e-9) - np.ceil(n_lo - 1e-9) + 1 + 2 * ring
                    count = float(np.prod(per_axis))
                if ok:
                    total += count
                if not ok or total > MAX_POOL_SIZE:
                    raise ConfigurationError(
                        f"joint {j + 1}: the wavelet pool would exceed {MAX_POOL_SIZE} wavelets "
                        f"(dilation {m}: step {step:.3g} rad/s)"
                    )

    @property
    def size(self) -> int:
        """Total number of pool wavelets over all joints."""
        return int(self.joint_offsets[-1])

    @property
    def n_joints(self) -> int:
        """Number of networks (joints)."""
        return len(self.specs)

    def joint_slice(self, joint: int) -> slice:
        """Global index range of ``joint``'s pool."""
        return slice(int(self.joint_offsets[joint]), int(self.joint_offsets[joint + 1]))

    def joint_size(self, joint: int) -> int:
        """Pool size ``K_j`` of ``joint``."""
        return int(self.joint_offsets[joint + 1] - self.joint_offsets[joint])

    def index_of(self, joint: int, m: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Global indices of ``(m, n)`` pairs of ``joint`` (m (P,), n (P, d)); -1 if absent."""
        m = np.asarray(m, dtype=np.int64).reshape(-1)
        n = np.asarray(n, dtype=np.int64).reshape(m.size, -1)
        out = np.full(m.size, -1, dtype=np.int64)
        for mv in np.unique(m):
            block = self._blocks[joint].get(int(mv))
            if block is None:
                continue
            sel = np.flatnonzero(m == mv)
            rel = n[sel] - block.n_lo
            inside = np.all((rel >= 0) & (rel < np.asarray(block.shape)), axis=1)
            if np.any(inside):
                flat = np.ravel_multi_index(tuple(rel[inside].T), block.shape)
                out[sel[inside]] = block.offset + flat
        return out

    def neighbours(self, indices: np.ndarray) -> np.ndarray:
        """Pool neighbours in ``Z^(1+d)`` of the global ``indices`` (sorted, unique).

        See the module docstring for the rescaling across dilations; the input wavelets
        themselves are not returned unless they neighbour another input wavelet.
        """
        indices = np.unique(np.asarray(indices, dtype=np.int64))
        found: list[np.ndarray] = []
        for j in np.unique(self.joint[indices]):
            idx = indices[self.joint[indices] == j]
            d = self.specs[j].d
            centre = self.centre[idx, :d]
            offsets = np.asarray(list(product((0, 1, 2), repeat=d)), dtype=np.int64)
            for dm in (-1, 0, 1):
                m_new = self.m[idx] + dm
                step = self.a0 ** m_new.astype(float) * self.b0
                r = centre / step[:, None]
                lo = np.ceil(r - 1.0 - 1e-9).astype(np.int64)
                cand = lo[:, None, :] + offsets[None, :, :]
                ok = np.all(cand <= r[:, None, :] + 1.0 + 1e-9, axis=2)
                cand_m = np.broadcast_to(m_new[:, None], ok.shape)[ok]
                got = self.index_of(int(j), cand_m, cand[ok])
                got = got[got >= 0]
                if dm == 0:
                    got = got[~np.isin(got, idx)]
                found.append(got)
        if not found:
            return np.zeros(0, dtype=np.int64)
        return np.unique(np.concatenate(found))

    def _seeds(self, joint: int) -> np.ndarray:
        """Coarsest-dilation wavelets nearest the origin, one per open orthant."""
        spec = self.specs[joint]
        sl = self.joint_slice(joint)
        coarse = np.flatnonzero(self.m[sl] == spec.m_max) + sl.start
        n = self.n[coarse, : spec.d]
        dist = np.sum(self.centre[coarse, : spec.d] ** 2, axis=1)
        chosen = []
        for signs in product((-1, 1), repeat=spec.d):
            s = np.asarray(signs)
            for ok in (np.all(np.sign(n) == s, axis=1), np.all(np.sign(n) * s >= 0, axis=1)):
                if np.any(ok):
                    chosen.append(int(coarse[ok][np.argmin(dist[ok])]))
                    break
            else:
                chosen.append(int(coarse[np.argmin(dist)]))
        return np.unique(np.asarray(chosen, dtype=np.int64))

    def evaluate(self, qd: np.ndarray, indices: np.ndarray) -> np.ndarray:
        """Raw wavelet values ``psi_k(qd)`` (N, P) for global ``indices`` (any joints)."""
        qd = np.ascontiguousarray(np.atleast_2d(np.asarray(qd, dtype=float)))
        indices = np.asarray(indices, dtype=np.int64)
        return pool_wavelets(
            qd,
            np.ascontiguousarray(self.input_index[indices]),
            np.ascontiguousarray(self.centre_scaled[indices]),
            np.ascontiguousarray(self.inv_scale[indices]),
            np.ascontiguousarray(self.amplitude[indices]),
        )

    def label(self, index: int) -> str:
        """Human-readable ``m=..,n=(..)`` of a global index."""
        d = int(self.d[index])
        n = ",".join(str(int(v)) for v in self.n[index, :d])
        return f"m={int(self.m[index])},n=({n})"


class _SingleSampleTorque:
    """The active wavelets of a :class:`WaveletNetwork` as a wavelet table, for one sample.

    The table is what :func:`~teleop_force.friction.terms.wavelet_network_torque_into`
    evaluates: one column per distinct wavelet with ``centre_scaled``, ``inv_scale`` and its
    weight ``amplitude * coefficient`` on every joint (rows), the velocities it reads in
    ``inputs``. Wavelets that several joints' networks share (same inputs, ``m`` and ``n``:
    the Omni's joints 2 and 3 read the same velocities) are one column with a weight per
    joint. Columns are sorted by their inputs; ``runs`` lists the ``[start, end)`` of each
    run of columns reading the same velocities, so the kernel's inner loops need no gather.
    """

    def __init__(self, network: WaveletNetwork) -> None:
        """Build the table of ``network``'s active set (weights: :meth:`load_coefficients`)."""
        pool = network.pool
        idx = network.active_global_indices()
        self.structure_version = network.structure_version
        self.coef_version = -1
        self.n = network.n_joints
        # one column per distinct wavelet (inputs, m, n), in order of first appearance;
        # `slot[k]` is active wavelet k's (vectorised: this runs when the structure changes)
        slot = np.zeros(idx.size, dtype=np.int64)
        unique = np.zeros(0, dtype=np.int64)
        if idx.size:
            keys = np.concatenate((pool.input_index[idx], pool.m[idx, None], pool.n[idx]), axis=1)
            _, first_at, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
            appearance = np.argsort(first_at, kind="stable")
            group_rank = np.empty(appearance.size, dtype=np.int64)
            group_rank[appearance] = np.arange(appearance.size)
            slot = group_rank[np.asarray(inverse).reshape(-1)]
            unique = idx[first_at[appearance]]
        d = pool.dmax
        inputs = pool.input_index[unique].reshape(unique.size, d)
        order = np.lexsort(inputs.T[::-1]) if unique.size else np.zeros(0, dtype=np.int64)
        rank = np.empty(unique.size, dtype=np.int64)
        rank[order] = np.arange(unique.size)
        unique = unique[order]
        self.inputs = np.ascontiguousarray(inputs[order], dtype=np.int64)
        changed = np.any(self.inputs[1:] != self.inputs[:-1], axis=1)
        starts = [0, *(np.flatnonzero(changed) + 1).tolist()]
        ends = [*starts[1:], unique.size]
        self.runs = np.array(list(zip(starts, ends, strict=True)) if unique.size else [],
                             dtype=np.int64).reshape(-1, 2)  # fmt: skip
        self.table = np.zeros((d + 1 + self.n, unique.size))
        self.table[:d] = pool.centre_scaled[unique].T
        self.table[d] = pool.inv_scale[unique]
        self._weights = d + 1
        self.idx = idx
        self.slot = rank[slot]
        self.joint = pool.joint[idx]
        self.amplitude = pool.amplitude[idx]

    def load_coefficients(self, network: WaveletNetwork) -> None:
        """Take ``network``'s current coefficients."""
        w = np.zeros((self.table.shape[1], self.n))
        np.add.at(w, (self.slot, self.joint), self.amplitude * network.coefficients_at(self.idx))
        self.table[self._weights :] = w.T
        self.coef_version = network._coef_version

    def __call__(self, qd: Sequence[float] | np.ndarray) -> np.ndarray:
        """Torque per joint at ``qd``."""
        out = np.zeros(self.n)
        psi = np.empty(self.table.shape[1])
        wavelet_network_torque_into(
            np.asarray(qd, dtype=float), self.inputs, self.table, self.runs, psi, out
        )
        return out


class WaveletNetworkEntry(Struct):
    """``wn``: joint networks, the pool constants, the fallback and the coverage map."""

    n_joints: JointCount
    joints: list[WaveletJointEntry]
    a0: Finite = A0_DEFAULT
    b0: Finite = B0_DEFAULT
    edge_ring: bool = True
    fallback: CoupledCoulombViscous | None = None
    coverage: CoverageMap | None = None
    on_fallback: bool = False

    def __post_init__(self) -> None:
        n = self.n_joints
        if self.on_fallback and self.fallback is None:
            raise ModelFileError("a network on its fallback needs the fallback", column="fallback")
        if len(self.joints) != n:
            raise ModelFileError(f"expected {n} joint networks", column="joints")
        for j, joint in enumerate(self.joints):
            if max(joint.inputs) >= n:
                raise ModelFileError(
                    f"velocity index {max(joint.inputs)} >= {n}", column=f"joints[{j}].inputs"
                )
        if self.coverage is not None:
            if self.coverage.n_joints != n:
                raise ModelFileError(
                    f"{self.coverage.n_joints} grids for {n} joints", column="coverage.grids"
                )
            for j in range(n):
                if max(self.coverage.grid_inputs(j)) >= n:
                    raise ModelFileError(
                        f"reads a velocity beyond joint {n}", column=f"coverage.grids[{j}].inputs"
                    )


class WaveletNetwork(FrictionModel):
    """Per-joint wavelet networks (eq. 6) over a fixed pool with a changing active set."""

    kind: ClassVar[str] = "wn"

    def __init__(
        self,
        n_joints: int,
        specs: Sequence[WaveletJointSpec],
        *,
        a0: float = A0_DEFAULT,
        b0: float = B0_DEFAULT,
        edge_ring: bool = True,
        fallback: CoupledCoulombViscous | None = None,
        coverage: CoverageMap | None = None,
        on_fallback: bool = False,
    ) -> None:
        """Create the networks with only the seed wavelets active (coefficients 0).

        ``coverage`` defaults to an empty :class:`CoverageMap` over the networks' regions.
        ``on_fallback``: the network adds to its fallback instead of replacing it (module
        docstring).
        """
        specs = tuple(specs)
        if len(specs) != n_joints:
            raise ModelError(f"wn: need one WaveletJointSpec per joint, got {len(specs)}")
        self.pool = WaveletPool(specs, n_joints, a0, b0, edge_ring)
        self._coef = np.zeros(self.pool.size)
        self._active = np.zeros(self.pool.size, dtype=bool)
        self._active[self.pool.seeds] = True
        self._structure_version = 0
        self._coef_version = 0
        self._single: _SingleSampleTorque | None = None
        self._refresh_active()
        self.fallback = fallback
        self._on_fallback = bool(on_fallback)
        if fallback is not None and fallback.n_joints != n_joints:
            raise ModelError("wn: fallback model has a different number of joints")
        if coverage is not None and coverage.n_joints != n_joints:
            raise ModelError(f"wn: coverage map has {coverage.n_joints} grids, need {n_joints}")
        if coverage is not None:
            for j in range(n_joints):
                inputs = coverage.grid_inputs(j)
                if max(inputs) >= n_joints:
                    raise ModelError(f"wn: coverage grid {j + 1} reads velocity {max(inputs) + 1}")
        self.coverage: CoverageMap | None = (
            coverage
            if coverage is not None
            else CoverageMap.for_inputs(
                [s.inputs for s in specs],
                [s.x_min_rad_s for s in specs],
                [s.x_max_rad_s for s in specs],
            )
        )
        super().__init__(n_joints, self._coef[self._active_idx])

    # -- structure -------------------------------------------------------------------------

    @property
    def specs(self) -> tuple[WaveletJointSpec, ...]:
        """Per-joint network specifications."""
        return self.pool.specs

    @property
    def on_fallback(self) -> bool:
        """Whether the network adds to its fallback (``CV + w WN``) instead of replacing it."""
        return self._on_fallback

    @property
    def structure(self) -> str:
        """The structure's name (:data:`~teleop_force.friction.kinds.WN_STRUCTURES`)."""
        return wn_structure_name(self._on_fallback)

    def base_torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction at ``qd`` (N x n) that the network is not fitted to: what it adds to.

        Its fallback's when :attr:`on_fallback` (what training and online adaptation subtract
        from the network's target), else zeros.
        """
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        if self._on_fallback and self.fallback is not None:
            return np.asarray(self.fallback.torque(qd), dtype=float)
        return np.zeros(qd.shape)

    def path_base_torque(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        """:meth:`base_torque` along a path of one stream: a sticking fallback follows ``q_rad``."""
        fallback = self.fallback
        if self._on_fallback and fallback is not None and fallback.sticking_rad > 0.0:
            return np.asarray(fallback.path_torque(q_rad, qd_rad_s), dtype=float)
        return self.base_torque(qd_rad_s)

    def path_torque(
        self, q_rad: np.ndarray, qd_rad_s: np.ndarray, blend: bool = True
    ) -> np.ndarray:
        """:meth:`blended_torque` (``blend``; else :meth:`torque`) along a path of one stream.

        The fallback's Coulomb terms follow ``q_rad`` when it has a sticking state.
        """
        qd = np.atleast_2d(np.asarray(qd_rad_s, dtype=float))
        fallback = self.fallback
        if not blend:
            return np.asarray(self.torque(qd), dtype=float)
        if fallback is None or not fallback.sticking_rad > 0.0:
            return self.blended_torque(qd)
        return trust_blend_values(
            np.ascontiguousarray(self.coverage_weight(qd), dtype=float),
            np.ascontiguousarray(self.torque(qd), dtype=float),
            np.ascontiguousarray(fallback.path_torque(q_rad, qd), dtype=float),
            self.on_fallback,
        )

    @property
    def structure_version(self) -> int:
        """Counter bumped on every change of the active set."""
        return self._structure_version

    @property
    def coef_version(self) -> int:
        """Counter bumped on every change of the coefficients."""
        return self._coef_version

    def _refresh_active(self) -> None:
        self._active_idx = np.flatnonzero(self._active)
        self._active_joint = self.pool.joint[self._active_idx]
        self._counts = tuple(
            int(v) for v in np.bincount(self._active_joint, minlength=self.pool.n_joints)
        )
        self._joint_active = tuple(
            self._active_idx[self._active_joint == j] for j in range(self.pool.n_joints)
        )
        self._structure_version += 1
        self._coef_version += 1

    def parameter_counts(self) -> tuple[int, ...]:
        """Active wavelets per joint (changes with the structure)."""
        return self._counts

    def active_global_indices(self, joint: int | None = None) -> np.ndarray:
        """Sorted global pool indices of the active wavelets (of ``joint``, or of all)."""
        out = self._active_idx if joint is None else self._joint_active[joint]
        return out.copy()

    def active_indices(self, joint: int) -> np.ndarray:
        """Active wavelets of ``joint`` as indices into that joint's pool (0..K_j-1)."""
        return self._joint_active[joint] - int(self.pool.joint_offsets[joint])

    def is_active(self, indices: np.ndarray) -> np.ndarray:
        """Whether the global ``indices`` are active."""
        return self._active[np.asarray(indices, dtype=np.int64)]

    def activate(self, indices: np.ndarray) -> np.ndarray:
        """Make global ``indices`` active (new ones with coefficient 0); return the new ones."""
        indices = np.unique(np.asarray(indices, dtype=np.int64))
        new = indices[~self._active[indices]]
        if new.size:
            self._coef[new] = 0.0
            self._active[new] = True
            self._refresh_active()
        return new

    def deactivate(self, indices: np.ndarray) -> None:
        """Remove global ``indices`` from the network (their coefficients become 0)."""
        indices = np.unique(np.asarray(indices, dtype=np.int64))
        if indices.size:
            self._coef[indices] = 0.0
            self._active[indices] = False
            self._refresh_active()

    def set_structure(self, joint: int, indices: np.ndarray, coefficients: np.ndarray) -> None:
        """Replace ``joint``'s active set by global ``indices`` with ``coefficients``."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        coefficients = np.asarray(coefficients, dtype=float).reshape(-1)
        if indices.shape != coefficients.shape:
            raise ModelError("wn: one coefficient per wavelet needed")
        sl = self.pool.joint_slice(joint)
        if indices.size and (indices.min() < sl.start or indices.max() >= sl.stop):
            raise ModelError(f"wn: wavelet index outside joint {joint + 1}'s pool")
        self._coef[sl] = 0.0
        self._active[sl] = False
        self._active[indices] = True
        self._coef[indices] = coefficients
        self._refresh_active()

    def coefficients_at(self, indices: np.ndarray) -> np.ndarray:
        """Coefficients of global ``indices`` (a copy; 0 for inactive wavelets)."""
        return self._coef[np.asarray(indices, dtype=np.int64)]

    def set_coefficients_at(self, indices: np.ndarray, values: np.ndarray) -> None:
        """Write coefficients of active global ``indices``."""
        indices = np.asarray(indices, dtype=np.int64)
        if not np.all(self._active[indices]):
            raise ModelError("wn: cannot set the coefficient of an inactive wavelet")
        self._coef[indices] = values
        self._coef_version += 1

    # -- FrictionModel API -----------------------------------------------------------------

    @property
    def parameters(self) -> np.ndarray:
        """Coefficients of the active wavelets, joint by joint (read-only copy)."""
        out = self._coef[self._active_idx]
        out.flags.writeable = False
        return out

    @parameters.setter
    def parameters(self, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=float).reshape(-1)
        if values.shape != self._active_idx.shape:
            raise ModelError(
                f"wn: expected {self._active_idx.size} parameters (active), got {values.size}"
            )
        self._coef[self._active_idx] = values
        self._coef_version += 1

    def joint_parameters(self, joint: int) -> np.ndarray:
        """Coefficients of ``joint``'s active wavelets (a copy)."""
        return self._coef[self._joint_active[joint]]

    def set_joint_parameters(self, joint: int, values: np.ndarray) -> None:
        """Overwrite ``joint``'s active coefficients."""
        values = np.asarray(values, dtype=float).reshape(-1)
        if values.shape != self._joint_active[joint].shape:
            raise ModelError(f"wn: joint {joint + 1} has {self._counts[joint]} active wavelets")
        self._coef[self._joint_active[joint]] = values
        self._coef_version += 1

    def parameter_names(self, joint: int) -> list[str]:
        """``c{j}[m=..,n=(..)]`` for every active wavelet of ``joint``, 1-based joint."""
        return [f"c{joint + 1}[{self.pool.label(int(k))}]" for k in self._joint_active[joint]]

    def _joint_inputs(self, joint: int, qd: np.ndarray) -> np.ndarray:
        return qd[:, list(self.specs[joint].inputs)]

    def basis_at(self, joint: int, qd: np.ndarray, indices: np.ndarray) -> np.ndarray:
        """Wavelets with global ``indices`` (all of ``joint``) at ``qd`` (N x n) -> (N x P)."""
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        indices = np.asarray(indices, dtype=np.int64)
        d = self.specs[joint].d
        x = self._joint_inputs(joint, qd)
        out = np.empty((qd.shape[0], indices.size))
        chunk = max(1, _EVAL_CHUNK_ELEMENTS // max(1, indices.size))
        cs = self.pool.centre_scaled[indices, :d]
        inv = self.pool.inv_scale[indices]
        amp = self.pool.amplitude[indices]
        for start in range(0, qd.shape[0], chunk):
            stop = min(start + chunk, qd.shape[0])
            out[start:stop] = psi_block(x[start:stop], cs, inv, amp)
        return out

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """Active wavelets of ``joint`` at ``qd`` (N x n) -> (N x p_j)."""
        return self.basis_at(joint, qd, self._joint_active[joint])

    def torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction torque [N m] at ``qd`` ((n,) -> (n,) or (N, n) -> (N, n)), in chunks."""
        qd = np.asarray(qd, dtype=float)
        single = qd.ndim == 1
        batch = qd.reshape(1, -1) if single else qd
        if batch.ndim != 2 or batch.shape[1] != self.n_joints:
            raise ModelError(f"wn: expected {self.n_joints} velocities, got {qd.shape}")
        if batch.shape[0] <= 4:
            psi = self.pool.evaluate(batch, self._active_idx)
            weighted = psi * self._coef[self._active_idx]
            out = np.zeros((batch.shape[0], self.n_joints))
            for k in range(batch.shape[0]):
                out[k] = np.bincount(self._active_joint, weighted[k], minlength=self.n_joints)
            return out[0] if single else out
        out = np.zeros((batch.shape[0], self.n_joints))
        for j in range(self.n_joints):
            idx = self._joint_active[j]
            if idx.size == 0:
                continue
            d = self.specs[j].d
            x = self._joint_inputs(j, batch)
            cs = self.pool.centre_scaled[idx, :d]
            inv = self.pool.inv_scale[idx]
            amp = self.pool.amplitude[idx]
            c = self._coef[idx]
            chunk = max(1, _EVAL_CHUNK_ELEMENTS // idx.size)
            for start in range(0, batch.shape[0], chunk):
                stop = min(start + chunk, batch.shape[0])
                out[start:stop, j] = psi_block(x[start:stop], cs, inv, amp) @ c
        return out[0] if single else out

    def torque_one(self, qd: Sequence[float] | np.ndarray) -> np.ndarray:
        """Friction torque [N m] at one velocity sample ``qd`` (n,) -> (n,): the streaming path.

        Equals :meth:`torque` up to rounding (the same compiled wavelet, summed in another
        order, see :class:`_SingleSampleTorque`).
        """
        return self._single_sample()(qd)

    def _single_sample(self) -> _SingleSampleTorque:
        kernel = self._single
        if kernel is None or kernel.structure_version != self._structure_version:
            kernel = self._single = _SingleSampleTorque(self)
        if kernel.coef_version != self._coef_version:
            kernel.load_coefficients(self)
        return kernel

    def streaming_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(inputs, table, runs)`` of the active wavelets, up to date, for one sample.

        The arguments of :func:`~teleop_force.friction.terms.wavelet_network_torque_into`
        (see :class:`_SingleSampleTorque`); the arrays are replaced, not changed, when the
        structure changes, and their weights rewritten when the coefficients do.
        """
        kernel = self._single_sample()
        return kernel.inputs, kernel.table, kernel.runs

    # -- coverage-aware blending -------------------------------------------------------------

    def coverage_weight(self, qd: np.ndarray) -> np.ndarray:
        """Coverage trust of every joint's network at ``qd`` (N x n) -> (N x n), in [0, 1]."""
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        if self.coverage is None:
            return np.ones((qd.shape[0], self.n_joints))
        return self.coverage.trust(qd)

    def blended_torque(self, qd: np.ndarray) -> np.ndarray:
        """Coverage-aware estimate ``w WN(qd) + (1 - w) fallback(qd)`` per joint.

        With :attr:`on_fallback`, ``fallback(qd) + w WN(qd)``. ``w`` is
        :meth:`coverage_weight`; needs a ``fallback`` model (raises ModelError).
        """
        if self.fallback is None:
            raise ModelError("wn: blended_torque needs a fitted coupled-CV fallback model")
        qd = np.asarray(qd, dtype=float)
        single = qd.ndim == 1
        batch = np.atleast_2d(qd)
        w = self.coverage_weight(batch)
        out = trust_blend_values(
            np.ascontiguousarray(w, dtype=float),
            np.ascontiguousarray(self.torque(batch), dtype=float),
            np.ascontiguousarray(self.fallback.torque(batch), dtype=float),
            self.on_fallback,
        )
        return out[0] if single else out

    # -- serialisation -----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """Serialise pool definition, active set (as ``[m, n...]``), coefficients, extras."""
        joints = []
        for j, spec in enumerate(self.specs):
            idx = self._joint_active[j]
            d = spec.d
            active = [[int(self.pool.m[k]), *(int(v) for v in self.pool.n[k, :d])] for k in idx]
            entry = spec.to_dict()
            entry["active"] = active
            entry["coefficients"] = [float(v) for v in self._coef[idx]]
            joints.append(entry)
        return {
            "kind": self.kind,
            "n_joints": self.n_joints,
            "a0": self.pool.a0,
            "b0": self.pool.b0,
            "edge_ring": self.pool.edge_ring,
            "joints": joints,
            "fallback": None if self.fallback is None else self.fallback.to_dict(),
            "coverage": None if self.coverage is None else self.coverage.to_dict(),
            "on_fallback": self.on_fallback,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WaveletNetwork:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field.

        Every number must be finite, the active wavelets inside their joint's pool (each
        once), one coefficient per active wavelet, the fallback and coverage map of the same
        joints.
        """
        entry = read_entry(data, WaveletNetworkEntry, dec_hook=built_by())
        specs = [joint.spec() for joint in entry.joints]
        field = "joints"
        try:
            net = cls(
                entry.n_joints, specs, a0=entry.a0, b0=entry.b0, edge_ring=entry.edge_ring,
                fallback=entry.fallback, coverage=entry.coverage, on_fallback=entry.on_fallback,
            )  # fmt: skip
            if entry.coverage is None:
                net.coverage = None
            for j, joint in enumerate(entry.joints):
                d = specs[j].d
                field = f"joints[{j}].active"
                if any(len(row) != 1 + d for row in joint.active):
                    raise ModelFileError(f"expected a list of [m, n1..n{d}] rows")
                active = np.array(joint.active, dtype=np.int64).reshape(-1, 1 + d)
                idx = net.pool.index_of(j, active[:, 0], active[:, 1:])
                if np.any(idx < 0):
                    row = int(np.flatnonzero(idx < 0)[0])
                    raise ModelFileError(f"wavelet {active[row].tolist()} is outside the pool")
                if np.unique(idx).size != idx.size:
                    raise ModelFileError("a wavelet is listed twice")
                field = f"joints[{j}].coefficients"
                if len(joint.coefficients) != idx.size:
                    raise ModelFileError(f"expected {idx.size} numbers, one per active wavelet")
                net.set_structure(j, idx, np.array(joint.coefficients))
        except FILE_ERRORS as exc:
            raise file_error(exc, field, "wavelet-network model") from None
        return net
