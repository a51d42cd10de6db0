import math

from teleop_force.transport.messages import SafetyState
from web.status import Trust, TrustInputs, assess, banner_html


def fresh(**kw):
    base = {"estimate_age_s": 0.01, "joint_state_age_s": 0.01}
    base.update(kw)
    return TrustInputs(**base)


def test_green_only_when_fresh_trained_and_finite():
    v = assess(fresh(coverage_weight=(1.0, 0.9, 0.95)))
    assert v.trust is Trust.TRUSTED and v.trustworthy
    assert v.headline == "ESTIMATE TRUSTWORTHY" and not v.reasons and v.short == "estimate OK"


def test_waiting_and_stale():
    assert assess(TrustInputs()).trust is Trust.WAITING
    v = assess(fresh(estimate_age_s=1.3))
    assert v.trust is Trust.UNTRUSTED and "STALE" in v.headline
    assert any("1.3 s" in r for r in v.reasons)


def test_untrained_ground_names_the_joints():
    v = assess(fresh(untrained_joints=(1, 2)))
    assert v.trust is Trust.UNTRUSTED and "UNTRAINED GROUND" in v.headline
    assert v.short == "UNTRAINED GROUND"
    assert "joints 2, 3" in v.reasons[0]


def test_singular_nan_force():
    v = assess(fresh(force_nan=True))
    assert not v.trustworthy and "SINGULAR" in v.headline and v.short == "SINGULAR"


def test_holding_is_shown_but_does_not_change_trust():
    v = assess(
        fresh(status_state=SafetyState.HOLDING, status_reason="force limit", status_age_s=0.1)
    )
    assert v.trustworthy and v.safety_alert
    assert v.safety_line == "slave HOLDING: force limit"
    v = assess(fresh(status_state=SafetyState.FOLLOWING, status_age_s=5.0))
    assert not v.safety_alert and "5 s old" in v.safety_line


def test_banner_html_is_tagged_and_escaped():
    html = banner_html(
        assess(fresh(status_state=SafetyState.HOLDING, status_reason="<b>x</b>", status_age_s=0.0))
    )
    assert 'id="tf-trust" data-trust="trusted"' in html
    assert 'data-alert="true"' in html
    assert "&lt;b&gt;x&lt;/b&gt;" in html and "<b>x</b>" not in html
    red = banner_html(assess(fresh(untrained_joints=(0,))))
    assert 'data-trust="untrusted"' in red and "#d93025" in red
    assert math.isinf(TrustInputs().estimate_age_s)
