"""Every decoder and file reader, fed mutated valid inputs: only its own error type may escape.

``TELEOP_FUZZ_EXAMPLES=N`` sets the number of examples of every target (the defaults keep the
whole module near 20 s); ``python -m tests.fuzz.report`` runs them and prints the counts.
"""

from __future__ import annotations

import json
import os

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from .strategies import mutate_bytes, mutate_json, mutate_text
from .targets import (
    ROBOT_DH,
    ROBOT_TOML,
    TARGETS,
    URDF,
    exercise,
    model_seed_dicts,
    robot_input,
)

_OVERRIDE = os.environ.get("TELEOP_FUZZ_EXAMPLES")


def fuzz(default_examples: int):
    """Settings of one fuzz target: ``default_examples`` unless TELEOP_FUZZ_EXAMPLES is set."""
    return settings(
        max_examples=int(_OVERRIDE) if _OVERRIDE else default_examples,
        deadline=None,
        suppress_health_check=[
            HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much,
        ],
    )  # fmt: skip


def seeds_of(name: str) -> list[bytes]:
    return TARGETS[name].seeds()


def mutated(name: str, mutate=mutate_bytes) -> st.SearchStrategy[bytes]:
    return st.sampled_from(seeds_of(name)).flatmap(mutate)


header_then_noise = st.builds(
    lambda kind, version, body: b"TF" + bytes([version, kind]) + body,
    st.integers(0, 7), st.sampled_from([1, 1, 1, 0, 2, 255]), st.binary(max_size=300),
)  # fmt: skip
message_inputs = st.one_of(
    st.binary(max_size=300), header_then_noise, mutated("messages.decode"),
    mutated("messages.decode"),
)  # fmt: skip


@fuzz(400)
@given(message_inputs)
def test_fuzz_messages_decode(data):
    exercise(TARGETS["messages.decode"], data)


@fuzz(300)
@given(message_inputs)
def test_fuzz_each_message_class_decode(data):
    exercise(TARGETS["Message classes .decode"], data)


@fuzz(300)
@given(
    st.sampled_from(seeds_of("Message classes .from_json_dict")).flatmap(
        lambda seed: mutate_json(json.loads(seed))
    )
)
def test_fuzz_message_json(data):
    exercise(TARGETS["Message classes .from_json_dict"], data)


@fuzz(150)
@given(
    st.one_of(
        st.binary(max_size=2000),
        st.binary(max_size=2000).map(lambda b: b"\x89MCAP0\r\n" + b),
        mutated("MCAP session reader", lambda seed: mutate_bytes(seed, max_ops=8)),
        mutated("MCAP session reader", lambda seed: mutate_bytes(seed, max_ops=2)),
    )
)
def test_fuzz_mcap_session_reader(data):
    exercise(TARGETS["MCAP session reader"], data)


@fuzz(300)
@given(st.one_of(st.binary(max_size=300), mutated("ROS 2 decoders (CDR, attachment, token)")))
def test_fuzz_ros2_decoders(data):
    exercise(TARGETS["ROS 2 decoders (CDR, attachment, token)"], data)


@fuzz(200)
@given(st.one_of(st.binary(max_size=500), mutated("interchange CSV", mutate_text)))
def test_fuzz_interchange_csv(data):
    exercise(TARGETS["interchange CSV"], data)


robot_inputs = st.one_of(
    mutate_json(ROBOT_DH).map(lambda b: robot_input(".json", b)),
    mutate_text(ROBOT_TOML).map(lambda b: robot_input(".toml", b)),
    mutate_text(URDF).map(lambda b: robot_input(".urdf", b)),
)


@fuzz(150)
@given(robot_inputs)
def test_fuzz_robot_description_file(data):
    exercise(TARGETS["robot description file"], data)


model_inputs = st.one_of(
    st.sampled_from(model_seed_dicts()).flatmap(mutate_json),
    st.sampled_from(model_seed_dicts()).flatmap(
        lambda d: mutate_text(json.dumps(d, indent=1).encode())
    ),
)


@fuzz(150)
@given(model_inputs)
def test_fuzz_model_file(data):
    exercise(TARGETS["model file (DynamicModel.load)"], data)


@fuzz(100)
@given(model_inputs)
def test_fuzz_model_file_into_an_estimator(data):
    exercise(TARGETS["model file -> estimator (service load)"], data)


def test_the_seeds_themselves_are_accepted():
    for name, target in TARGETS.items():
        for seed in target.seeds():
            assert exercise(target, seed) == "accepted", name
