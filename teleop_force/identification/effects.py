"""Effects the residual loop adds to a model: torques linear in their parameters.

An effect is a :class:`BasisSpec` (which variable, which fixed shape, which modulation) and
its coefficients. Variables are named as in CONTRACT.md: ``q2`` (angle), ``q2-q3`` (angle
difference), ``qd1`` (velocity), ``tau3`` (the load on joint 3), ``t`` (time since start).

``tau<j>`` is the *rigid-body model* torque of joint ``j`` (low-pass filtered), not the measured
motor torque: the measured torque contains the very residual being explained, and as a
variable it "explains" 15-20 % of a clean recording's friction misfit by itself (measured on
simulated clean data). The model torque carries the same load (gravity, inertia, spring)
without that leak.

An effect acts on the joint it was found on, or, found on a coupled robot whose physics acts at
its model joints, at that model joint, reaching the motors through the coupling
(:attr:`FoundEffect.reach`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from teleop_force.errors import ModelError

SHAPES = ("constant", "linear", "smooth", "periodic", "abs", "stribeck")
MODULATIONS = ("none", "sign", "positive", "both")
_VARIABLE = re.compile(r"^(t|q(\d+)-q(\d+)|q(\d+)|qd(\d+)|tau(\d+))$")


def variable_values(
    name: str, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Values of the named variable at every sample (``t`` is time since the first sample)."""
    match = _VARIABLE.match(name)
    if match is None:
        raise ModelError(f"unknown effect variable {name!r}")
    n = q.shape[1]
    indices = [int(g) - 1 for g in match.groups()[1:] if g is not None]
    if any(not 0 <= i < n for i in indices):
        raise ModelError(f"effect variable {name!r} names a joint outside 1..{n}")
    if name == "t":
        return np.asarray(t_s, dtype=float) - float(t_s[0])
    if match.group(2) is not None:
        return q[:, indices[0]] - q[:, indices[1]]
    if match.group(4) is not None:
        return q[:, indices[0]]
    if match.group(5) is not None:
        return qd[:, indices[0]]
    return tau[:, indices[0]]


@dataclass(frozen=True)
class BasisSpec:
    """How an effect's basis is computed.

    Attributes:
        joint: Joint the torque acts on (0-based).
        variable: Variable the effect depends on (``q2``, ``q2-q3``, ``qd1``, ``tau3``, ``t``).
        shape: ``constant``; ``linear`` (x); ``smooth`` (Gaussian bumps over ``[lo, hi]``);
            ``periodic`` (sin/cos of ``k * frequency * x``, k = 1..harmonics); ``abs`` (|x|);
            ``stribeck`` (``exp(-(x / v)^2)`` for each scale v).
        modulation: ``none``; ``sign`` (times ``sgn(qd_joint)``); ``positive`` (times
            ``[qd_joint > 0]``); ``both`` (the basis and the basis times ``sgn(qd_joint)``: a
            shape with a direction-dependent part, like a cable's hysteresis).
        lo, hi: Range of ``smooth`` bumps.
        count: Number of bumps (``smooth``).
        frequency: Base spatial frequency [rad/unit of x] (``periodic``).
        harmonics: Harmonics (``periodic``).
        scales: Velocity scales (``stribeck``).

    """

    joint: int
    variable: str
    shape: str
    modulation: str = "none"
    lo: float = 0.0
    hi: float = 1.0
    count: int = 0
    frequency: float = 0.0
    harmonics: int = 0
    scales: tuple[float, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise ModelError(f"unknown effect shape {self.shape!r}")
        if self.modulation not in MODULATIONS:
            raise ModelError(f"unknown effect modulation {self.modulation!r}")
        if self.shape != "constant" and _VARIABLE.match(self.variable) is None:
            raise ModelError(f"unknown effect variable {self.variable!r}")
        if self.shape == "smooth" and (self.count < 2 or not self.hi > self.lo):
            raise ModelError("smooth effect needs count >= 2 and hi > lo")
        if self.shape == "periodic" and (self.harmonics < 1 or not self.frequency > 0):
            raise ModelError("periodic effect needs harmonics >= 1 and frequency > 0")
        if self.shape == "stribeck" and (not self.scales or min(self.scales) <= 0):
            raise ModelError("stribeck effect needs positive velocity scales")
        object.__setattr__(self, "scales", tuple(float(s) for s in self.scales))

    @property
    def size(self) -> int:
        """Number of basis functions."""
        return (2 if self.modulation == "both" else 1) * {
            "constant": 1,
            "linear": 1,
            "abs": 1,
            "smooth": self.count,
            "periodic": 2 * self.harmonics,
            "stribeck": len(self.scales),
        }[self.shape]

    @property
    def kind(self) -> str:
        """Short name of the effect family, as reported by ``residual``."""
        var = self.variable
        if self.shape == "constant":
            return "direction-dependent offset" if self.modulation != "none" else "offset"
        if self.shape == "stribeck":
            return "stribeck friction"
        if var == "t":
            return "friction drift" if self.modulation != "none" else "torque drift"
        if var.startswith("tau"):
            return "load-dependent friction"
        if var.startswith("qd"):
            return "cross-joint coupling"
        if self.modulation == "both":
            return "position-dependent torque, direction-dependent part"
        if self.modulation != "none":
            return "position-dependent friction"
        if self.shape == "periodic":
            return "position-periodic torque"
        return "position-dependent torque"

    def depends_on(self) -> list[str]:
        """Variables the effect depends on (the ``depends_on`` field of the report)."""
        names: list[str] = []
        if self.shape != "constant":
            names += self.variable.split("-") if "-" in self.variable else [self.variable]
        if self.modulation != "none":
            names.append(f"qd{self.joint + 1}")
        return list(dict.fromkeys(names))

    def describe(self) -> str:
        """One readable line."""
        var = "1" if self.shape == "constant" else self.variable
        mod = {
            "none": "",
            "sign": f" x sgn(qd{self.joint + 1})",
            "positive": f" x [qd{self.joint + 1} > 0]",
            "both": f" x (1, sgn(qd{self.joint + 1}))",
        }
        return f"joint {self.joint + 1}: {self.shape}({var}){mod[self.modulation]}"

    def basis(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Basis functions at every sample (N x size)."""
        n_samples = q.shape[0]
        if self.shape == "constant":
            phi = np.ones((n_samples, 1))
        else:
            x = variable_values(self.variable, t_s, q, qd, tau)
            if self.shape == "linear":
                phi = x[:, None]
            elif self.shape == "abs":
                phi = np.abs(x)[:, None]
            elif self.shape == "smooth":
                centres = np.linspace(self.lo, self.hi, self.count)
                width = (self.hi - self.lo) / (self.count - 1)
                phi = np.exp(-0.5 * ((x[:, None] - centres[None, :]) / width) ** 2)
            elif self.shape == "periodic":
                k = np.arange(1, self.harmonics + 1) * self.frequency
                phase = x[:, None] * k[None, :]
                phi = np.concatenate((np.sin(phase), np.cos(phase)), axis=1)
            else:
                scales = np.asarray(self.scales)
                phi = np.exp(-((x[:, None] / scales[None, :]) ** 2))
        if self.modulation == "sign":
            phi = phi * np.sign(qd[:, self.joint])[:, None]
        elif self.modulation == "positive":
            phi = phi * (qd[:, self.joint] > 0)[:, None]
        elif self.modulation == "both":
            phi = np.concatenate((phi, phi * np.sign(qd[:, self.joint])[:, None]), axis=1)
        return phi


class FoundEffect:
    """An effect with identified coefficients: ``tau_joint = basis @ coefficients``.

    ``reach``: where the torque lands, one weight per motor joint (None: on :attr:`joint`
    alone). An effect acting at a *model* joint ``k`` of a coupled robot reaches the motors
    through the coupling like any model torque, ``tau_motor = T^T e_k tau``: its reach is row
    ``k`` of ``T`` (scaled so that the weight on :attr:`joint` is 1), e.g. a cable spring at the
    dVRK MTM's wrist platform loads joints 2 and 3 with the cable's ratio.
    """

    def __init__(
        self,
        spec: BasisSpec,
        coefficients: np.ndarray,
        explained: float = 0.0,
        reach: np.ndarray | None = None,
    ) -> None:
        """Bind a basis to its coefficients (``explained``: held-out variance fraction)."""
        coefficients = np.asarray(coefficients, dtype=float).reshape(-1)
        if coefficients.shape != (spec.size,):
            raise ModelError(f"effect {spec.describe()} needs {spec.size} coefficients")
        if reach is not None:
            reach = np.asarray(reach, dtype=float).reshape(-1)
            if reach.size <= spec.joint or not np.all(np.isfinite(reach)):
                raise ModelError(
                    f"effect {spec.describe()}: reach needs a finite weight per joint"
                    f" (at least {spec.joint + 1}), got {reach.tolist()}"
                )
        self.spec = spec
        self.coefficients = coefficients
        self.explained = float(explained)
        self.reach = reach

    @property
    def joint(self) -> int:
        """Joint the effect was found on (0-based)."""
        return self.spec.joint

    def weights(self, n_joints: int) -> np.ndarray:
        """Motor torque per unit of the effect's torque (``n_joints``,)."""
        if self.reach is None:
            return np.eye(n_joints)[self.spec.joint]
        if self.reach.size != n_joints:
            raise ModelError(
                f"effect {self.spec.describe()} reaches {self.reach.size} joints, not {n_joints}"
            )
        return self.reach

    def torque(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Torque on all joints (N x n): on :attr:`joint`, or spread by :attr:`reach`."""
        q = np.asarray(q, dtype=float)
        value = self.spec.basis(t_s, q, qd, tau) @ self.coefficients
        return value[:, None] * self.weights(q.shape[1])[None, :]

    def to_dict(self) -> dict[str, Any]:
        """Serialise."""
        spec = asdict(self.spec)
        spec["scales"] = list(self.spec.scales)
        out = {
            "kind": "basis",
            "spec": spec,
            "coefficients": self.coefficients.tolist(),
            "explained": self.explained,
        }
        if self.reach is not None:
            out["reach"] = self.reach.tolist()
        return out


def describe_reach(joint: int, reach: Sequence[float] | None) -> str:
    """Where an effect acts, for reports: ``joint 4`` or ``j2 +0.6697, j3 -0.6697, j4 +1``.

    ``joint`` is 1-based (as in the residual JSON); ``reach`` the motor weights or None.
    """
    if reach is None:
        return f"joint {joint}"
    return ", ".join(f"j{i + 1} {w:+.4g}" for i, w in enumerate(reach) if w != 0.0)


def effect_from_dict(data: dict[str, Any]) -> FoundEffect:
    """Rebuild an effect from :meth:`FoundEffect.to_dict`."""
    if not isinstance(data, dict) or data.get("kind") != "basis":
        raise ModelError("effect entry is not a basis effect")
    spec = dict(data["spec"])
    spec["scales"] = tuple(spec.get("scales", ()))
    return FoundEffect(
        BasisSpec(**spec),
        np.asarray(data["coefficients"], dtype=float),
        float(data.get("explained", 0.0)),
        None if data.get("reach") is None else np.asarray(data["reach"], dtype=float),
    )
