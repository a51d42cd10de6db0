import contextlib
import json
import math
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from teleop_force.errors import MessageError
from teleop_force.transport import messages as m

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ROUND = settings(max_examples=150, deadline=None)

seqs = st.integers(0, 2**32 - 1)
stamps = st.integers(-(2**63), 2**63 - 1)
finite = st.floats(allow_nan=False, allow_infinity=False)


@st.composite
def joint_vectors(draw, count: int, n: int | None = None):
    n = draw(st.integers(1, 12)) if n is None else n
    return [tuple(draw(st.lists(finite, min_size=n, max_size=n))) for _ in range(count)]


@st.composite
def joint_states(draw):
    q, qd, effort = draw(joint_vectors(3))
    return m.JointState(draw(seqs), draw(stamps), q, qd, effort)


@st.composite
def joint_setpoints(draw):
    (q,) = draw(joint_vectors(1))
    return m.JointSetpoint(draw(seqs), draw(stamps), q)


@st.composite
def contact_forces(draw):
    (f,) = draw(joint_vectors(1, n=3))
    return m.ContactForce(draw(seqs), draw(stamps), f)


@st.composite
def force_estimates(draw):
    n = draw(st.integers(1, 20))
    tau, cov, motor, model = draw(joint_vectors(4, n=n))
    flags = tuple(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    f = tuple(draw(st.lists(st.floats(allow_infinity=False), min_size=3, max_size=3)))
    return m.ForceEstimateMessage(
        draw(seqs), draw(stamps), draw(seqs), f, tau, flags, cov, motor, model
    )


@st.composite
def statuses(draw):
    state = draw(st.sampled_from(list(m.SafetyState)))
    return m.Status(draw(seqs), draw(stamps), state, draw(st.text(max_size=40)))


any_message = st.one_of(
    joint_states(), joint_setpoints(), contact_forces(), force_estimates(), statuses()
)


def same(a, b) -> bool:
    """Equality that treats NaN force components as equal."""
    if isinstance(a, m.ForceEstimateMessage) and isinstance(b, m.ForceEstimateMessage):
        fa = tuple("nan" if math.isnan(x) else x for x in a.f_n)
        fb = tuple("nan" if math.isnan(x) else x for x in b.f_n)
        return fa == fb and a.to_json_dict() == b.to_json_dict()
    return a == b


@ROUND
@given(any_message)
def test_binary_round_trip(message):
    data = message.encode()
    assert data[:2] == b"TF" and data[2] == m.VERSION and data[3] == message.TYPE
    assert same(type(message).decode(data), message)
    assert same(m.decode(data), message)
    assert same(m.decode(bytearray(data)), message)
    assert same(m.decode(memoryview(data)), message)
    version, kind, seq, t_ns = m.peek_header(data)
    assert (version, kind, seq, t_ns) == (m.VERSION, message.TYPE, message.seq, message.t_ns)


@ROUND
@given(any_message)
def test_json_round_trip(message):
    text = json.dumps(message.to_json_dict(), allow_nan=False)  # valid JSON for Foxglove
    assert same(type(message).from_json_dict(json.loads(text)), message)


@pytest.mark.parametrize(
    "cls", [m.JointState, m.JointSetpoint, m.ContactForce, m.ForceEstimateMessage, m.Status]
)
def test_json_schema_describes_every_field(cls):
    schema = cls.json_schema()
    assert schema["type"] == "object"
    assert schema["title"] == m.schema_name(cls)
    assert m.MESSAGE_CLASSES_BY_SCHEMA[schema["title"]] is cls
    json.dumps(schema)


def test_layout_sizes_match_the_docstring():
    n = 3
    js = m.JointState(1, 2, (0.0,) * n, (0.0,) * n, (0.0,) * n)
    assert len(js.encode()) == 17 + 24 * n
    assert len(m.JointSetpoint(1, 2, (0.0,) * n).encode()) == 17 + 8 * n
    assert len(m.ContactForce(1, 2, (0.0, 0.0, 0.0)).encode()) == 40
    fe = m.ForceEstimateMessage(
        1, 2, 3, (0.0,) * 3, (0.0,) * n, (True,) * n, (0,) * n, (0,) * n, (0,) * n
    )
    assert len(fe.encode()) == 45 + 32 * n + 1
    assert len(m.Status(1, 2, m.SafetyState.HOLDING, "ab").encode()) == 19 + 2


def test_joint_state_field_offsets():
    js = m.JointState(7, -5, (1.0, 2.0), (3.0, 4.0), (5.0, 6.0))
    data = js.encode()
    assert struct.unpack_from("<IqB", data, 4) == (7, -5, 2)
    assert struct.unpack_from("<6d", data, 17) == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


def test_force_estimate_bitmask():
    flags = (True, False, True, True, False, False, False, False, True)
    fe = m.ForceEstimateMessage(
        0, 0, 0, (0.0,) * 3, (0.0,) * 9, flags, (0,) * 9, (0,) * 9, (0,) * 9
    )
    data = fe.encode()
    assert data[-2:] == bytes([0b00001101, 0b00000001])
    assert fe.on_trained_ground_mask == 0b1_0000_1101
    assert m.ForceEstimateMessage.decode(data).on_trained_ground == flags


def test_version_mismatch_is_rejected():
    data = bytearray(m.JointSetpoint(1, 2, (0.5,)).encode())
    data[2] = m.VERSION + 1
    with pytest.raises(MessageError, match="version"):
        m.JointSetpoint.decode(bytes(data))
    with pytest.raises(MessageError, match="version"):
        m.decode(bytes(data))


def test_wrong_type_magic_and_length_are_rejected():
    data = m.JointSetpoint(1, 2, (0.5, 0.25)).encode()
    with pytest.raises(MessageError, match="type"):
        m.JointState.decode(data)
    with pytest.raises(MessageError, match="magic"):
        m.JointSetpoint.decode(b"XX" + data[2:])
    with pytest.raises(MessageError, match="bytes"):
        m.JointSetpoint.decode(data[:-1])
    with pytest.raises(MessageError, match="bytes"):
        m.JointSetpoint.decode(data + b"\0")
    with pytest.raises(MessageError):
        m.decode(b"")
    with pytest.raises(MessageError, match="unknown message type"):
        m.decode(b"TF\x01\x63" + bytes(20))
    with pytest.raises(MessageError, match="expected bytes"):
        m.decode("TF")  # type: ignore[arg-type]


def test_zero_joints_rejected():
    header = struct.pack("<2sBBIqB", b"TF", 1, m.MessageType.JOINT_SETPOINT, 0, 0, 0)
    with pytest.raises(MessageError, match="joint count is 0"):
        m.JointSetpoint.decode(header)
    with pytest.raises(MessageError):
        m.JointSetpoint(0, 0, ())


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_joint_values_rejected(bad):
    with pytest.raises(MessageError, match="non-finite"):
        m.JointState(0, 0, (bad, 0.0), (0.0, 0.0), (0.0, 0.0))
    data = struct.pack(
        "<2sBBIqB6d", b"TF", 1, m.MessageType.JOINT_STATE, 0, 0, 2, 0.0, bad, 0, 0, 0, 0
    )
    with pytest.raises(MessageError, match="non-finite"):
        m.JointState.decode(data)


def test_force_estimate_nan_force_allowed_inf_not():
    args = ((0.1,), (True,), (1.0,), (0.0,), (0.0,))
    nan_fe = m.ForceEstimateMessage(0, 0, 0, (math.nan, 0.0, 0.0), *args)
    assert math.isnan(m.ForceEstimateMessage.decode(nan_fe.encode()).f_n[0])
    assert nan_fe.to_json_dict()["f_n"]["x"] is None
    with pytest.raises(MessageError, match="infinite"):
        m.ForceEstimateMessage(0, 0, 0, (math.inf, 0.0, 0.0), *args)
    data = bytearray(nan_fe.encode())
    struct.pack_into("<d", data, 21, math.inf)
    with pytest.raises(MessageError, match="infinite"):
        m.ForceEstimateMessage.decode(bytes(data))


def test_force_estimate_unused_mask_bits_rejected():
    fe = m.ForceEstimateMessage(
        0, 0, 0, (0.0,) * 3, (0.0,) * 3, (True,) * 3, (0,) * 3, (0,) * 3, (0,) * 3
    )
    data = bytearray(fe.encode())
    data[-1] |= 0b1000
    with pytest.raises(MessageError, match="bits"):
        m.ForceEstimateMessage.decode(bytes(data))


def test_status_reason_and_state_checks():
    st_ok = m.Status(3, 4, m.SafetyState.FOLLOWING, "ok ✓")
    assert m.Status.decode(st_ok.encode()) == st_ok
    data = bytearray(st_ok.encode())
    data[16] = 99
    with pytest.raises(MessageError, match="state"):
        m.Status.decode(bytes(data))
    bad_utf8 = struct.pack("<2sBBIqBH", b"TF", 1, m.MessageType.STATUS, 0, 0, 1, 2) + b"\xff\xfe"
    with pytest.raises(MessageError, match="UTF-8"):
        m.Status.decode(bad_utf8)
    with pytest.raises(MessageError):
        m.Status(0, 0, 42)
    with pytest.raises(MessageError):
        m.Status(0, 0, m.SafetyState.HOLDING, "x" * 70_000)
    with pytest.raises(MessageError):
        m.Status.from_json_dict({"seq": 0, "t_ns": 0, "state": "dancing", "reason": ""})


@pytest.mark.parametrize(
    "make",
    [
        lambda: m.JointState(-1, 0, (0.0,), (0.0,), (0.0,)),
        lambda: m.JointState(2**32, 0, (0.0,), (0.0,), (0.0,)),
        lambda: m.JointState(0, 2**63, (0.0,), (0.0,), (0.0,)),
        lambda: m.JointState(0.5, 0, (0.0,), (0.0,), (0.0,)),
        lambda: m.JointState(0, 0, (0.0, 1.0), (0.0,), (0.0,)),
        lambda: m.JointState(0, 0, ("a",), (0.0,), (0.0,)),
        lambda: m.JointState(0, 0, None, (0.0,), (0.0,)),
        lambda: m.JointSetpoint(0, 0, (0.0,) * 256),
        lambda: m.ContactForce(0, 0, (0.0, 1.0)),
        lambda: m.ForceEstimateMessage(0, 0, 0, (0.0,) * 3, (0.0,), (True, True), (0,), (0,), (0,)),
        lambda: m.ForceEstimateMessage(0, 0, 0, (0.0,) * 3, (0.0,), 5, (0,), (0,), (0,)),
    ],
)
def test_invalid_construction_raises_message_error(make):
    with pytest.raises(MessageError):
        make()


def test_from_json_dict_rejects_bad_objects():
    for cls in m.MESSAGE_CLASSES.values():
        for bad in ({}, {"seq": 1}, [], None, {"seq": "x", "t_ns": 0}):
            with pytest.raises(MessageError):
                cls.from_json_dict(bad)  # type: ignore[arg-type]


def test_sequence_gap():
    assert m.sequence_gap(5, 6) == 0
    assert m.sequence_gap(5, 9) == 3
    assert m.sequence_gap(2**32 - 1, 0) == 0


def test_fields_normalised_to_tuples_of_float():
    js = m.JointState(1, 2, [1, 2], [3, 4], [5, 6])
    assert js.q_rad == (1.0, 2.0) and isinstance(js.q_rad[0], float)
    assert hash(js) == hash(m.JointState(1, 2, (1.0, 2.0), (3.0, 4.0), (5.0, 6.0)))


# ------------------------------------------------------------------------------ fuzzing

DECODERS = [m.decode, *(cls.decode for cls in m.MESSAGE_CLASSES.values())]


def only_message_error(data: bytes) -> None:
    for decode in DECODERS:
        with contextlib.suppress(MessageError):
            decode(data)


@FUZZ
@given(st.binary(max_size=400))
def test_fuzz_random_bytes(data):
    only_message_error(data)


@FUZZ
@given(st.sampled_from(list(m.MessageType)), st.integers(0, 255), st.binary(max_size=400))
def test_fuzz_valid_header_random_body(kind, version_delta, body):
    version = m.VERSION if version_delta < 200 else version_delta
    only_message_error(b"TF" + bytes([version, kind]) + body)


@st.composite
def mutated(draw):
    data = bytearray(draw(any_message).encode())
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "set", "truncate", "extend", "delete"]))
        if op == "truncate":
            del data[draw(st.integers(0, len(data))) :]
        elif op == "extend":
            data += draw(st.binary(min_size=1, max_size=16))
        elif not data:
            continue
        elif op == "delete":
            del data[draw(st.integers(0, len(data) - 1))]
        else:
            i = draw(st.integers(0, len(data) - 1))
            if op == "flip":
                data[i] ^= 1 << draw(st.integers(0, 7))
            else:
                data[i] = draw(st.integers(0, 255))
    return bytes(data)


@FUZZ
@given(mutated())
def test_fuzz_mutated_valid_messages(data):
    only_message_error(data)


def test_unpack_joint_state_equals_decode_and_checks_the_same() -> None:
    js = m.JointState(7, 123, (0.1, 0.2, 0.3), (1.0, 2.0, 3.0), (-0.1, 0.0, 0.5))
    seq, t_ns, n, values = m.unpack_joint_state(js.encode())
    assert (seq, t_ns, n) == (7, 123, 3)
    assert values == (*js.q_rad, *js.qd_rad_s, *js.effort_nm)
    bad = bytearray(js.encode())
    bad[17:25] = struct.pack("<d", math.nan)
    for payload in (bytes(bad), js.encode()[:-1], m.ContactForce(1, 2, (0.0, 0.0, 0.0)).encode()):
        with pytest.raises(MessageError):
            m.JointState.decode(payload)
        with pytest.raises(MessageError):
            m.unpack_joint_state(payload)


def test_pack_force_estimate_is_the_encoding_of_the_message() -> None:
    flags = (True, False, True)
    message = m.ForceEstimateMessage(
        5, 99, 4, (math.nan, 1.0, 2.0), (0.1, 0.2, 0.3), flags, (1.0, 0.2, 0.7),
        (3.0, 4.0, 5.0), (6.0, 7.0, 8.0),
    )  # fmt: skip
    values = [
        *message.f_n, *message.tau_ext_nm, *message.coverage_weight,
        *message.tau_motor_filtered_nm, *message.tau_model_filtered_nm,
    ]  # fmt: skip
    assert m.pack_force_estimate(5, 99, 4, 3, values, 0b101) == message.encode()
