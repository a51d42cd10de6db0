"""The command-line flags that choose the estimator, shared by the CLI and the service.

A leaf module (argparse only), so that building a parser imports neither pinocchio nor numba.
"""

from __future__ import annotations

import argparse

#: The estimators: the paper's filtered dynamics (``filter``) or the generalised-momentum
#: observer (``observer``, :mod:`teleop_force.estimation.momentum_observer`).
ESTIMATORS = ("filter", "observer")


def add_estimator_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the estimator's flags (each the model's value when absent).

    ``--estimator``, ``--observer-hz``, ``--observer-prefilter-hz``,
    ``--observer-prefilter-stages``, ``--observer-output-hz``, ``--count-observer``.
    """
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
    parser.add_argument(
        "--observer-prefilter-hz", type=float, default=None, metavar="HZ",
        help="cutoff of each stage of the observer's pre-filter of angles and torques [Hz] "
        "(default: the model's)",
    )  # fmt: skip
    parser.add_argument(
        "--observer-prefilter-stages", type=int, choices=(1, 2), default=None,
        help="first-order stages of the observer's pre-filter (default: the model's)",
    )  # fmt: skip
    parser.add_argument(
        "--observer-output-hz", type=float, default=None, metavar="HZ",
        help="cutoff of the second-order Butterworth on the observer's estimate [Hz]; 0: none "
        "(default: the model's)",
    )  # fmt: skip
    parser.add_argument(
        "--count-observer", action=argparse.BooleanOptionalAction, default=None,
        help="estimate on the encoder count observer's angles, or on the readings (default: "
        "the model's; the streaming estimator needs the model's encoder counts)",
    )  # fmt: skip


#: The estimator flags and their ``argparse`` destinations (the ``FilterConfig`` fields they
#: set), in the order they are forwarded.
_FLAGS = (
    ("--estimator", "estimator"),
    ("--observer-hz", "observer_hz"),
    ("--observer-prefilter-hz", "observer_prefilter_hz"),
    ("--observer-prefilter-stages", "observer_prefilter_stages"),
    ("--observer-output-hz", "observer_output_hz"),
    ("--count-observer", "count_observer"),
)


def given_estimator_flags(args: argparse.Namespace) -> dict[str, str | float | int | bool]:
    """Return the estimator flags ``args`` holds: ``FilterConfig`` field name -> value."""
    values = {name: getattr(args, name) for _, name in _FLAGS}
    return {name: value for name, value in values.items() if value is not None}


def forwarded_estimator_arguments(args: argparse.Namespace) -> tuple[str, ...]:
    """Return the estimator flags ``args`` holds, as words for a child's command line."""
    given = given_estimator_flags(args)
    words: list[str] = []
    for flag, name in _FLAGS:
        if name in given:
            value = given[name]
            if isinstance(value, bool):  # a switch: --flag or --no-flag
                words.append(flag if value else "--no-" + flag[2:])
            else:
                words += [flag, value if isinstance(value, str) else repr(value)]
    return tuple(words)
