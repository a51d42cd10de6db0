"""Can the force estimate be trusted right now? The verdict and the banner that shows it.

Rules, in order (the first that applies sets the headline, every one that applies is listed):

1. no ForceEstimate yet, or the last one arrived more than ``stale_after_s`` ago: grey
   ("waiting") or red ("stale") -- not trustworthy;
2. any joint reported ``on_trained_ground = False`` within the last ``untrained_hold_s``: red
   "UNTRAINED GROUND" -- not trustworthy (held a moment so a brief excursion stays readable);
3. the last estimate has a NaN force (tip Jacobian near singular): red -- no estimate;
4. otherwise green "ESTIMATE TRUSTWORTHY".

The slave's safety state (HOLDING, STOPPED, reason) is shown on its own amber line; it does
not change the trust verdict.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Final

from teleop_force.transport.messages import SafetyState

STALE_AFTER_S: Final = 0.25
UNTRAINED_HOLD_S: Final = 0.5


class Trust(Enum):
    """The verdict shown by the banner."""

    WAITING = "waiting"
    TRUSTED = "trusted"
    UNTRUSTED = "untrusted"


@dataclass(frozen=True)
class TrustInputs:
    """What the verdict is computed from (all ages in seconds, ``inf`` if never received).

    Attributes:
        estimate_age_s: Time since the last ForceEstimate arrived.
        untrained_joints: 0-based joints off trained ground within the hold window.
        force_nan: The last estimate had no force (NaN).
        coverage_weight: Coverage weight per joint of the last estimate (may be empty).
        status_state: Last safety state of the slave, ``None`` if none received.
        status_reason: Its reason text.
        status_age_s: Time since the last Status arrived.
        joint_state_age_s: Time since the last JointState arrived.

    """

    estimate_age_s: float = math.inf
    untrained_joints: tuple[int, ...] = ()
    force_nan: bool = False
    coverage_weight: tuple[float, ...] = ()
    status_state: SafetyState | None = None
    status_reason: str = ""
    status_age_s: float = math.inf
    joint_state_age_s: float = math.inf


@dataclass(frozen=True)
class Verdict:
    """The assessed state: a trust level, a headline and the reasons behind it."""

    trust: Trust
    headline: str
    short: str
    reasons: tuple[str, ...] = ()
    safety_line: str | None = None
    safety_alert: bool = False
    notes: tuple[str, ...] = field(default=())

    @property
    def trustworthy(self) -> bool:
        """Whether the force estimate may be used right now."""
        return self.trust is Trust.TRUSTED


def _joints(indices: Sequence[int]) -> str:
    names = [str(j + 1) for j in indices]
    return ("joint " if len(names) == 1 else "joints ") + ", ".join(names)


def assess(inputs: TrustInputs, stale_after_s: float = STALE_AFTER_S) -> Verdict:
    """Turn the current inputs into a :class:`Verdict` (see the module docstring)."""
    reasons: list[str] = []
    notes: list[str] = []
    if math.isinf(inputs.estimate_age_s):
        reasons.append("no force estimate received yet")
    elif inputs.estimate_age_s > stale_after_s:
        reasons.append(f"estimate stale: last one {inputs.estimate_age_s:.1f} s ago")
    fresh = not reasons
    if fresh and inputs.untrained_joints:
        reasons.append(
            f"UNTRAINED GROUND ({_joints(inputs.untrained_joints)}): the friction model was not "
            "trained at these velocities"
        )
    if fresh and inputs.force_nan:
        reasons.append("no force: tip Jacobian near singular (NaN estimate)")
    if math.isinf(inputs.joint_state_age_s):
        notes.append("no joint state received")
    elif inputs.joint_state_age_s > stale_after_s:
        notes.append(f"joint state stale ({inputs.joint_state_age_s:.1f} s)")
    if inputs.coverage_weight:
        notes.append("coverage weight " + " ".join(f"{w:.2f}" for w in inputs.coverage_weight))

    if math.isinf(inputs.estimate_age_s):
        trust, headline, short = Trust.WAITING, "WAITING FOR FORCE ESTIMATE", "waiting"
    elif not fresh:
        trust, headline, short = Trust.UNTRUSTED, "ESTIMATE STALE - DO NOT TRUST", "STALE"
    elif inputs.untrained_joints:
        trust = Trust.UNTRUSTED
        headline, short = "UNTRAINED GROUND - ESTIMATE NOT TRUSTWORTHY", "UNTRAINED GROUND"
    elif inputs.force_nan:
        trust = Trust.UNTRUSTED
        headline, short = "NO FORCE ESTIMATE (SINGULAR JACOBIAN)", "SINGULAR"
    else:
        trust, headline, short = Trust.TRUSTED, "ESTIMATE TRUSTWORTHY", "estimate OK"

    safety_line, safety_alert = None, False
    if inputs.status_state is not None:
        name = inputs.status_state.name
        safety_line = f"slave {name}"
        if inputs.status_reason:
            safety_line += f": {inputs.status_reason}"
        if inputs.status_age_s > 2.0:
            safety_line += f" (status {inputs.status_age_s:.0f} s old)"
        safety_alert = inputs.status_state in (SafetyState.HOLDING, SafetyState.STOPPED)
    return Verdict(trust, headline, short, tuple(reasons), safety_line, safety_alert, tuple(notes))


_COLOURS: Final = {
    Trust.WAITING: ("#5f6368", "#ffffff"),
    Trust.TRUSTED: ("#1e8e3e", "#ffffff"),
    Trust.UNTRUSTED: ("#d93025", "#ffffff"),
}


def banner_html(verdict: Verdict) -> str:
    """HTML of the banner: a big coloured headline, reasons, and the slave safety line."""
    bg, fg = _COLOURS[verdict.trust]
    parts = [
        f'<div id="tf-trust" data-trust="{verdict.trust.value}" style="background:{bg};'
        f"color:{fg};padding:14px 10px;border-radius:8px;text-align:center;"
        'font:700 22px/1.25 system-ui,sans-serif;letter-spacing:0.5px">'
        f"{html.escape(verdict.headline)}</div>"
    ]
    if verdict.reasons:
        items = "".join(f"<li>{html.escape(r)}</li>" for r in verdict.reasons)
        parts.append(
            f'<ul id="tf-reasons" style="margin:6px 0 0 0;padding-left:18px;color:{bg};'
            f'font:600 14px/1.3 system-ui,sans-serif">{items}</ul>'
        )
    if verdict.safety_line is not None:
        sbg = "#f29900" if verdict.safety_alert else "#e8eaed"
        sfg = "#000000" if verdict.safety_alert else "#3c4043"
        weight = 700 if verdict.safety_alert else 500
        parts.append(
            f'<div id="tf-safety" data-alert="{str(verdict.safety_alert).lower()}" '
            f'style="margin-top:6px;background:{sbg};color:{sfg};padding:6px 10px;'
            f'border-radius:6px;font:{weight} 16px/1.3 system-ui,sans-serif">'
            f"{html.escape(verdict.safety_line)}</div>"
        )
    if verdict.notes:
        parts.append(
            '<div style="margin-top:4px;color:#5f6368;font:12px/1.3 system-ui,sans-serif">'
            + html.escape(" | ".join(verdict.notes))
            + "</div>"
        )
    return '<div style="margin:2px 0 6px 0">' + "".join(parts) + "</div>"


__all__ = [
    "STALE_AFTER_S",
    "UNTRAINED_HOLD_S",
    "Trust",
    "TrustInputs",
    "Verdict",
    "assess",
    "banner_html",
]
