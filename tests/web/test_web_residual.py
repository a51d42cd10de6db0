"""The dashboard's residual-watch folder: the latest report, rendered with its command."""

from __future__ import annotations

import math

from web_ros2 import Talker, attachment, wait_for

from teleop_force.errors import MessageError
from teleop_force.ros2 import topics
from teleop_force.ros2.node import Node
from teleop_force.transport import messages as m
from web.residual_view import STALE_AFTER_S, DiagnosticsInbox, diagnostics_markdown

COMMAND = "teleop-force residual RECORDING --model /abs/omni_sim.json"


def _report(finding: m.DiagnosticFinding | None, state: str = "watching") -> m.ServiceDiagnostics:
    return m.ServiceDiagnostics(
        seq=1, t_ns=0, device="slave", state=state, stream_s=80.0, baseline_complete=True,
        rms_torque_nm=(0.02, 0.15, 0.02),
        checks=(
            m.DiagnosticCheck(1, 120, "t", 0.4, 0.01, 0),
            m.DiagnosticCheck(2, 150, "tau2", 1e-12, 0.08, 6),
            m.DiagnosticCheck(3, 0, None, 1.0, math.nan, 0),
        ),
        finding=finding, command="" if finding is None else COMMAND,
    )  # fmt: skip


def test_the_inbox_keeps_the_latest_report_and_counts_malformed_ones() -> None:
    inbox = DiagnosticsInbox()
    assert inbox.latest is None and inbox.age_s() == math.inf
    report = _report(None)
    inbox.on_message(report, attachment(1))
    inbox.on_malformed("/slave/service/diagnostics", MessageError("not CDR"))
    assert inbox.latest is report and inbox.malformed == 1
    assert 0.0 <= inbox.age_s() < 60.0


def test_the_inbox_hears_the_service_diagnostics_topic(zenoh_pair) -> None:
    """Real sessions: a report in CDR arrives decoded; garbage and a bare sample are counted."""
    talker = Talker(zenoh_pair.listener)
    node = Node(zenoh_pair.connector, "teleop_force_dashboard")
    inbox = DiagnosticsInbox().subscribe(node, "slave")
    try:
        talker.wait_for_subscribers(topics.SERVICE_DIAGNOSTICS)
        talker.raw(topics.SERVICE_DIAGNOSTICS, b"\x00\x01\x00\x00{}", attachment(1))
        talker.raw(topics.SERVICE_DIAGNOSTICS, b"no attachment", None)
        finding = m.DiagnosticFinding(2, "tau2", 0.08, 0.012, 1e-12, 66.0, True)
        talker.service_diagnostics(_report(finding, "dependence"))
        wait_for(lambda: inbox.latest is not None and inbox.malformed == 2, "the report")
        got = inbox.latest
        assert got.finding == finding and got.command == COMMAND and len(got.checks) == 3
        assert diagnostics_markdown(got) == diagnostics_markdown(_report(finding, "dependence"))
    finally:
        inbox.close()
        node.close()
        talker.close()


def test_a_finding_is_shown_with_the_command_to_run_next() -> None:
    finding = m.DiagnosticFinding(2, "tau2", 0.08, 0.012, 1e-12, 66.0, True)
    text = diagnostics_markdown(_report(finding, "dependence"))
    assert "Dependence found" in text and "joint 2" in text and "`tau2`" in text
    assert "8.0 %" in text and COMMAND in text
    assert "| 3 | 0 | - | - |" in text  # a joint without a test shows dashes, not NaN


def test_watching_baseline_nothing_yet_and_stale() -> None:
    assert "no report" in diagnostics_markdown(None)
    assert "Watching: no dependence" in diagnostics_markdown(_report(None))
    assert "baseline" in diagnostics_markdown(_report(None, "baseline"))
    assert "stale" in diagnostics_markdown(_report(None), age_s=STALE_AFTER_S + 1.0)
    assert COMMAND not in diagnostics_markdown(_report(None))
