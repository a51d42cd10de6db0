"""The command-line flags that choose the estimator, shared by the CLI and the service.

A leaf module (argparse only), so that building a parser imports neither pinocchio nor numba.
"""

from __future__ import annotations

import argparse

#: The estimators: the paper's filtered dynamics (``filter``) or the generalised-momentum
#: observer (``observer``, :mod:`teleop_force.estimation.momentum_observer`).
ESTIMATORS = ("filter", "observer")


def add_estimator_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--estimator {filter,observer}`` and ``--observer-hz HZ`` (the model's when absent)."""
    parser.add_argument(
        "--estimator", choices=ESTIMATORS, default=None,
        help="estimator of the external torque: the filtered dynamics or the momentum "
        "observer (default: the model's; models identified now use the observer, model "
        "files from before it the filter)",
    )  # fmt: skip
    parser.add_argument(
        "--observer-hz", type=float, default=None, metavar="HZ",
        help="bandwidth of the momentum observer [Hz] (default: the model's)",
    )  # fmt: skip
