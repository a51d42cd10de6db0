"""Least-squares identification and its frozen result (the paper's Table I)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teleop_force.errors import DataError, ModelError


@dataclass(frozen=True, eq=False)
class Identification:
    """Result of a least-squares identification.

    Attributes:
        parameter_names: Name of each identified parameter.
        parameters: Estimated values.
        standard_deviations: Their standard deviations (from the residual variance).
        condition_number: Condition number of the column-scaled regressor.
        relative_rms: Relative RMS of the fitted torque per joint on the fitting data.
        samples: Number of time samples used.

    """

    parameter_names: tuple[str, ...]
    parameters: np.ndarray
    standard_deviations: np.ndarray
    condition_number: float
    relative_rms: np.ndarray
    samples: int

    def __post_init__(self) -> None:
        n = len(self.parameter_names)
        if self.parameters.shape != (n,) or self.standard_deviations.shape != (n,):
            raise ModelError("Identification: names, parameters and deviations differ in size")

    def relative_standard_deviations(self) -> np.ndarray:
        """``std / |value|`` (inf where the value is 0)."""
        with np.errstate(divide="ignore"):
            return self.standard_deviations / np.abs(self.parameters)

    def table(self, true_values: np.ndarray | None = None) -> str:
        """Render the paper's Table I as markdown: value +- std (and truth if given)."""
        head = "| # | parameter | value | std | rel. std |"
        rule = "|---|---|---|---|---|"
        if true_values is not None:
            head += " true | error |"
            rule += "---|---|"
        lines = [head, rule]
        rel = self.relative_standard_deviations()
        for i, name in enumerate(self.parameter_names):
            line = (
                f"| a{i + 1} | `{name}` | {self.parameters[i]:.4e}"
                f" | {self.standard_deviations[i]:.2e} | {rel[i]:.1%} |"
            )
            if true_values is not None:
                err = abs(self.parameters[i] - true_values[i]) / max(abs(true_values[i]), 1e-300)
                line += f" {true_values[i]:.4e} | {err:.1%} |"
            lines.append(line)
        lines.append("")
        lines.append(
            f"condition number (column-scaled) {self.condition_number:.1f}; samples {self.samples}"
        )
        return "\n".join(lines)


def relative_rms(measured: np.ndarray, estimated: np.ndarray) -> np.ndarray:
    """``RMS(x - x_hat) / RMS(x)`` per column (the paper's metric), as fractions."""
    measured = np.asarray(measured, dtype=float)
    error = measured - np.asarray(estimated, dtype=float)
    denom = np.sqrt(np.mean(measured**2, axis=0))
    denom[denom == 0.0] = np.nan
    return np.sqrt(np.mean(error**2, axis=0)) / denom


def least_squares(
    regressor: np.ndarray,
    torque: np.ndarray,
    names: list[str] | tuple[str, ...],
    ridge: float | np.ndarray = 0.0,
) -> Identification:
    """Joint-weighted least squares of ``torque (N, n) = regressor (N, n, p) @ theta``.

    ``ridge`` is added to the diagonal of the column-scaled normal equations: one value for
    every column, or one per column.

    Each joint's rows are weighted by the inverse of its residual standard deviation from an
    unweighted first pass, so joints with larger noise do not dominate. Standard deviations
    come from the weighted residual variance.
    """
    n_samples, n_joints, n_params = regressor.shape
    if torque.shape != (n_samples, n_joints):
        raise DataError(f"torque has shape {torque.shape}, expected {(n_samples, n_joints)}")
    if n_samples * n_joints <= n_params:
        raise DataError(f"{n_samples} samples cannot identify {n_params} parameters")
    if not (np.all(np.isfinite(regressor)) and np.all(np.isfinite(torque))):
        raise DataError("regressor or torque contains NaN or inf")
    weights = np.ones(n_joints)
    theta = np.zeros(n_params)
    for _ in range(2):
        w = regressor * weights[None, :, None]
        y = torque * weights[None, :]
        a = w.reshape(-1, n_params)
        b = y.reshape(-1)
        scale = np.linalg.norm(a, axis=0)
        scale[scale == 0.0] = 1.0
        a_scaled = a / scale
        gram = a_scaled.T @ a_scaled + np.diag(np.broadcast_to(ridge, (n_params,)))
        theta_scaled = np.linalg.solve(gram, a_scaled.T @ b)
        theta = theta_scaled / scale
        residual = torque - np.einsum("kjp,p->kj", regressor, theta)
        sigma = np.sqrt(np.mean(residual**2, axis=0))
        sigma[sigma == 0.0] = 1.0
        weights = 1.0 / sigma
    dof = max(a.shape[0] - n_params, 1)
    weighted_residual = b - a @ theta
    variance = float(weighted_residual @ weighted_residual) / dof
    singular = np.linalg.svd(a_scaled, compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else float("inf")
    covariance = variance * np.linalg.pinv(a_scaled.T @ a_scaled) / np.outer(scale, scale)
    fitted = np.einsum("kjp,p->kj", regressor, theta)
    return Identification(
        tuple(names),
        theta,
        np.sqrt(np.clip(np.diag(covariance), 0.0, None)),
        condition,
        relative_rms(torque, fitted),
        n_samples,
    )
