"""CDR payloads of the recorded messages: checked against a decoder written from the spec."""

import math
import struct

import numpy as np
import pytest

from teleop_force.errors import MessageError
from teleop_force.io import cdr_messages as cdr
from teleop_force.transport import messages as m
from tests.io import cdr_reference

T = 1_700_000_000_123_456_789


def examples(n):
    """One message of every class with ``n`` joints (awkward values included)."""
    q = tuple(0.1 * j - 0.37 for j in range(n))
    return [
        m.JointState(7, T, q, tuple(-x for x in q), tuple(1e-300 * (j + 1) for j in range(n))),
        m.JointSetpoint(2**32 - 1, -1, q),
        m.ContactForce(0, T, (0.0, -1.5, 0.25)),
        m.ForceEstimateMessage(
            9,
            T,
            8,
            (math.nan, 2.0, -3.0),
            q,
            tuple(j % 3 == 0 for j in range(n)),
            (0.5,) * n,
            q,
            tuple(x * 2 for x in q),
        ),
        m.Status(3, T, m.SafetyState.HOLDING, "master setpoint stale: 51.0 ms > 50 ms"),
        m.Status(4, T, m.SafetyState.FOLLOWING, "héllo ✓"),
        m.Status(5, T, m.SafetyState.STARTING, ""),
    ]


def reference_values(message):
    values = {"seq": message.seq, "t_ns": message.t_ns}
    if isinstance(message, m.Status):
        return {**values, "state": int(message.state), "reason": message.reason}
    for name in type(message).__slots__:
        if name not in values:
            field = getattr(message, name)
            values[name] = list(field) if isinstance(field, tuple) else field
    return cdr_reference.normalised(values)


#: Field offsets (after the 4-byte header) the module docstring documents, by class.
DOCUMENTED_OFFSETS = {
    m.JointState: lambda n: {
        "seq": 0, "t_ns": 8, "q_rad": 24, "qd_rad_s": 32 + 8 * n, "effort_nm": 40 + 16 * n,
    },
    m.JointSetpoint: lambda n: {"seq": 0, "t_ns": 8, "q_rad": 24},
    m.ContactForce: lambda n: {"seq": 0, "t_ns": 8, "f_n": 16},
    m.ForceEstimateMessage: lambda n: {
        "seq": 0, "t_ns": 8, "source_seq": 16, "f_n": 24, "tau_ext_nm": 56,
        "coverage_weight": 64 + 8 * n, "tau_motor_filtered_nm": 72 + 16 * n,
        "tau_model_filtered_nm": 80 + 24 * n, "on_trained_ground": 84 + 32 * n,
    },
    m.Status: lambda n: {"seq": 0, "t_ns": 8, "state": 16, "reason": 20},
}  # fmt: skip
DOCUMENTED_SIZES = {
    m.JointState: lambda n: 44 + 24 * n,
    m.JointSetpoint: lambda n: 28 + 8 * n,
    m.ContactForce: lambda n: 44,
    m.ForceEstimateMessage: lambda n: 88 + 33 * n,
}


@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_payloads_decode_with_the_spec_decoder_at_the_documented_offsets(n):
    for message in examples(n):
        cls = type(message)
        data = cdr.encode_cdr(message)
        assert data[:4] == b"\x00\x01\x00\x00"
        values, offsets = cdr_reference.decode(cdr.CDR_SCHEMAS[cls].text, data)
        assert cdr_reference.normalised(values) == reference_values(message)
        assert offsets == DOCUMENTED_OFFSETS[cls](n)
        if cls is m.Status:
            assert len(data) == 29 + len(message.reason.encode())
        else:
            assert len(data) == DOCUMENTED_SIZES[cls](n)
        # Alignment of every 8-byte field, counted after the header.
        for name, offset in offsets.items():
            if name in ("t_ns",) or name.endswith(("_rad", "_rad_s", "_nm", "_weight", "f_n")):
                assert offset % 8 == 0, (cls.__name__, name, offset)


@pytest.mark.parametrize("n", [1, 2, 3, 7])
def test_round_trip_of_every_class(n):
    for message in examples(n):
        back = cdr.decode_cdr(type(message), cdr.encode_cdr(message))
        assert type(back) is type(message)
        assert back.to_json_dict() == message.to_json_dict()


def test_schemas_are_ros2msg_texts_named_package_msg_type():
    assert set(cdr.CDR_SCHEMAS) == set(m.MESSAGE_CLASSES.values())
    for cls, schema in cdr.CDR_SCHEMAS.items():
        assert schema.name.startswith("teleop_force/msg/")
        assert cdr.MESSAGE_CLASSES_BY_CDR_SCHEMA[schema.name] is cls
        fields = [name for _, name, _ in cdr_reference.parse_schema(schema.text)]
        assert fields[:2] == ["seq", "t_ns"]
    status = cdr.CDR_SCHEMAS[m.Status].text
    for state in m.SafetyState:
        assert f"uint8 {state.name}={int(state)}" in status


@pytest.mark.parametrize("n", [1, 3, 7])
def test_a_block_converts_like_single_messages(n):
    for message in examples(n):
        cls = type(message)
        if not cdr.has_fixed_layout(cls):
            continue
        wire = [
            message.encode(),
            message.encode(),
        ]
        block = np.frombuffer(b"".join(wire), dtype=np.uint8).reshape(2, -1)
        result = cdr.wire_block_to_cdr(cls, block)
        assert result.accepted.tolist() == [True, True]
        assert result.cdr[0].tobytes() == cdr.encode_cdr(message)
        assert result.seq.tolist() == [message.seq] * 2
        assert result.t_ns.tolist() == [message.t_ns] * 2


def mutations(payload, rng, count):
    """Byte flips, non-finite floats and stray mask bits in copies of ``payload``."""
    out = [payload]
    for _ in range(count):
        data = bytearray(payload)
        kind = rng.integers(4)
        if kind == 0:
            for _ in range(rng.integers(1, 4)):
                data[rng.integers(len(data))] = rng.integers(256)
        elif kind == 1 and len(data) >= 25:
            at = int(rng.integers(16, len(data) - 8))
            data[at : at + 8] = struct.pack("<d", [math.inf, -math.inf, math.nan][rng.integers(3)])
        elif kind == 2:
            data[-1] |= 1 << int(rng.integers(8))
        else:
            data[int(rng.integers(4))] ^= 0xFF
        out.append(bytes(data))
    return out


@pytest.mark.parametrize("n", [1, 3, 7, 8, 9])
def test_a_block_accepts_exactly_what_the_wire_decoder_accepts(n):
    rng = np.random.default_rng(n)
    for message in examples(n):
        cls = type(message)
        if not cdr.has_fixed_layout(cls):
            continue
        payloads = mutations(message.encode(), rng, 400)
        block = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(payloads), -1)
        result = cdr.wire_block_to_cdr(cls, block)
        expected = []
        for payload in payloads:
            try:
                expected.append(type(m.decode(payload)) is cls)
            except MessageError:
                expected.append(False)
        assert result.accepted.tolist() == expected
        assert 0 < sum(expected) < len(expected)
        accepted = [p for p, ok in zip(payloads, expected, strict=True) if ok]
        for row, payload in zip(result.cdr, accepted, strict=True):
            assert row.tobytes() == cdr.encode_cdr(m.decode(payload))


def test_a_block_of_an_impossible_size_is_all_rejected():
    block = np.zeros((3, 18), dtype=np.uint8)
    result = cdr.wire_block_to_cdr(m.JointState, block)
    assert not result.accepted.any() and result.cdr.shape[0] == 0


@pytest.mark.parametrize("n", [1, 3])
def test_a_block_of_a_valid_size_with_no_valid_row_is_all_rejected(n):
    # every row the right size but malformed (bad magic): nothing left to convert (this once
    # raised ValueError, which killed the recorder's thread, found by the service fuzz test)
    for message in examples(n):
        cls = type(message)
        if not cdr.has_fixed_layout(cls):
            continue
        bad = b"XX" + message.encode()[2:]
        block = np.frombuffer(bad * 4, dtype=np.uint8).reshape(4, -1)
        result = cdr.wire_block_to_cdr(cls, block)
        assert not result.accepted.any()
        assert result.cdr.shape[0] == 0 and result.seq.shape == (0,) and result.t_ns.shape == (0,)


def test_joint_state_columns_match_single_decoding():
    messages = [
        m.JointState(i, T + i, (0.1 * i, 0.2, -0.3), (1.0, 2.0, 3.0), (0.0, -0.5, 1e-3 * i))
        for i in range(5)
    ]
    block = np.array([np.frombuffer(cdr.encode_cdr(x), np.uint8) for x in messages])
    seq, t_ns, q, qd, effort = cdr.joint_state_columns(block)
    assert seq.dtype == np.uint32 and t_ns.dtype == np.int64
    assert seq.tolist() == [x.seq for x in messages]
    assert t_ns.tolist() == [x.t_ns for x in messages]
    np.testing.assert_array_equal(q, [x.q_rad for x in messages])
    np.testing.assert_array_equal(qd, [x.qd_rad_s for x in messages])
    np.testing.assert_array_equal(effort, [x.effort_nm for x in messages])
    bad = block.copy()
    bad[2, 4 + 24 : 4 + 32] = np.frombuffer(struct.pack("<d", math.inf), np.uint8)
    with pytest.raises(MessageError, match="non-finite"):
        cdr.joint_state_columns(bad)
    bad = block.copy()
    bad[1, 4 + 16] = 2  # the element count of q_rad
    with pytest.raises(MessageError, match="element count"):
        cdr.joint_state_columns(bad)


def corrupt(data, at, value):
    out = bytearray(data)
    out[at] = value
    return bytes(out)


@pytest.mark.parametrize(
    ("message", "at", "value", "problem"),
    [
        (examples(3)[0], 0, 1, "header"),  # big-endian CDR: not what is written
        (examples(3)[0], 1, 0, "header"),
        (examples(3)[0], 4 + 5, 1, "padding"),  # padding after seq
        (examples(3)[0], 4 + 16, 4, "element count"),
        (examples(3)[3], 4 + 84 + 96 + 1, 2, "neither 0 nor 1"),  # a bool of on_trained_ground
        (examples(3)[4], 4 + 5, 1, "padding"),  # after seq
        (examples(3)[4], 4 + 18, 1, "padding"),  # after state
        (examples(3)[4], -1, ord("x"), "NUL"),
        (examples(3)[4], 4 + 20, 200, "length"),
        (examples(3)[4], 4 + 16, 9, "unknown safety state"),
        (examples(3)[2], 4 + 24 + 7, 0x7F, "non-finite"),  # f_y = -1.5 becomes NaN
    ],
)
def test_malformed_payloads_raise_message_error(message, at, value, problem):
    data = cdr.encode_cdr(message)
    bad = corrupt(data, at, value)
    assert bad != data
    with pytest.raises(MessageError, match=problem):
        cdr.decode_cdr(type(message), bad)


def test_wrong_sizes_raise_message_error():
    for message in examples(3):
        data = cdr.encode_cdr(message)
        for bad in (data[:-1], data + b"\0", b""):
            with pytest.raises(MessageError):
                cdr.decode_cdr(type(message), bad)
