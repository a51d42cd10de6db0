import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.transport import keys


def test_every_key_names_the_device():
    assert keys.measured_js("slave") == "omni/slave/measured_js"
    assert keys.setpoint_js("slave") == "omni/slave/setpoint_js"
    assert keys.measured_cf("slave") == "omni/slave/measured_cf"
    assert keys.estimated_cf("slave") == "omni/slave/estimated_cf"
    assert keys.status("slave") == "omni/slave/status"
    assert keys.service_model("slave") == "omni/slave/service/model"
    assert keys.service_stats("slave") == "omni/slave/service/stats"
    assert keys.alive("slave", "estimator") == "omni/slave/alive/estimator"


def test_wildcards():
    assert keys.alive_any() == "omni/*/alive/*"
    assert keys.alive_any("m1") == "omni/m1/alive/*"
    assert keys.any_device(keys.MEASURED_JS) == "omni/*/measured_js"
    assert keys.all_keys() == "omni/**"
    with pytest.raises(ConfigurationError):
        keys.any_device("nope")


@pytest.mark.parametrize("bad", ["", "a/b", "a*", "$x", "#", "what?", " lead", "trail ", 7])
def test_bad_device_ids_are_rejected(bad):
    with pytest.raises(ConfigurationError):
        keys.measured_js(bad)


def test_bad_role_is_rejected():
    with pytest.raises(ConfigurationError, match="role"):
        keys.alive("slave", "a/b")


def test_parse_round_trip():
    for make in (
        keys.measured_js,
        keys.setpoint_js,
        keys.measured_cf,
        keys.estimated_cf,
        keys.status,
        keys.service_model,
        keys.service_stats,
    ):
        parsed = keys.parse(make("dev-1"))
        assert parsed.device == "dev-1"
        assert make("x").endswith(parsed.kind)
    alive = keys.parse(keys.alive("dev-1", "master"))
    assert (alive.device, alive.kind, alive.role) == ("dev-1", keys.ALIVE, "master")


@pytest.mark.parametrize(
    "bad", ["other/dev/measured_js", "omni/dev", "omni/dev/unknown", "omni//x"]
)
def test_parse_rejects_foreign_keys(bad):
    with pytest.raises(ConfigurationError):
        keys.parse(bad)
