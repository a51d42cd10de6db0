"""rmw_zenoh's 33-byte attachment."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from teleop_force.errors import MessageError
from teleop_force.ros2.attachment import ATTACHMENT_SIZE, Attachment

INT64 = st.integers(-(2**63), 2**63 - 1)


def test_layout_is_seq_stamp_length_byte_then_gid():
    gid = bytes(range(16))
    data = Attachment(1, 1_700_000_000_123_456_789, gid).encode()
    assert len(data) == ATTACHMENT_SIZE == 33
    assert struct.unpack_from("<qq", data) == (1, 1_700_000_000_123_456_789)
    assert data[16] == 0x10
    assert data[17:] == gid


@given(INT64, INT64, st.binary(min_size=16, max_size=16))
def test_round_trip(seq, stamp, gid):
    assert Attachment.decode(Attachment(seq, stamp, gid).encode()) == Attachment(seq, stamp, gid)


@pytest.mark.parametrize(
    "data",
    [b"", bytes(32), bytes(34), bytes(16) + b"\x0f" + bytes(16), bytes(16) + b"\x11" + bytes(16)],
)
def test_wrong_size_or_gid_length_raises(data):
    with pytest.raises(MessageError):
        Attachment.decode(data)


def test_bad_values_raise():
    with pytest.raises(MessageError):
        Attachment(2**63, 0, bytes(16))
    with pytest.raises(MessageError):
        Attachment(0, 0, bytes(15))
