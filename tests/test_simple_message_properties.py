"""The simple_message codec, property-based: any bytes are decoded or refused with ProtocolError
(nothing else escapes, and nothing decoded carries a NaN or an infinity); encoding then decoding
is the identity on float32 values; values the wire cannot carry are refused naming the field."""

from __future__ import annotations

import contextlib
import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from robots.drivers import simple_message as sm

INT32 = st.integers(-(2**31), 2**31 - 1)
FLOAT32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
JOINTS = st.lists(FLOAT32, min_size=6, max_size=6)
NON_FINITE = st.sampled_from([math.nan, math.inf, -math.inf])
# Finite doubles that no float32 holds (the wire would make them infinite).
BEYOND_FLOAT32 = st.floats(min_value=sm.FLOAT32_MAX * (1 + 1e-6), allow_infinity=False).flatmap(
    lambda x: st.sampled_from([x, -x])
)


@st.composite
def framed(draw) -> bytes:
    """A prefix and header of a known type with the right length, and a body of random bytes
    (so NaN and infinity bit patterns turn up in the reals), or a near miss of any of these."""
    msg_type = draw(st.sampled_from(sorted(sm.BODY_SIZES)))
    size = sm.BODY_SIZES[msg_type]
    length = draw(st.sampled_from([sm.HEADER.size + size, sm.HEADER.size + size + 4, -1]))
    comm = draw(st.sampled_from([sm.TOPIC, sm.SERVICE_REQUEST, sm.SERVICE_REPLY]))
    body = draw(st.binary(min_size=size, max_size=size) | st.binary(max_size=size + 8))
    return struct.pack("<iiii", length, msg_type, comm, sm.SUCCESS) + body


def _finite(decoded: object) -> bool:
    if isinstance(decoded, sm.JointTrajPt):
        values = [*decoded.joints_rad, decoded.velocity, decoded.duration_s]
        return all(math.isfinite(v) for v in values)
    if isinstance(decoded, np.ndarray):
        return bool(np.isfinite(decoded).all())
    return isinstance(decoded, sm.RobotStatus)


@given(st.binary(max_size=160) | framed())
def test_any_bytes_are_decoded_or_refused_with_the_protocol_error(data):
    try:
        header, decoded = sm.decode(data)
    except sm.ProtocolError as e:
        assert str(e) and "\n" not in str(e)
        return
    assert header.msg_type in sm.BODY_SIZES
    assert _finite(decoded)


@given(st.binary(max_size=80))
def test_any_body_is_decoded_or_refused_by_each_decoder(body):
    for decoder in (sm.decode_traj_pt, sm.decode_joint_position, sm.decode_status):
        with contextlib.suppress(sm.ProtocolError):
            assert _finite(decoder(body))


@given(INT32, JOINTS, FLOAT32, FLOAT32)
def test_a_point_of_float32_values_survives_encode_and_decode_exactly(seq, joints, v, duration):
    point = sm.JointTrajPt(seq, np.array(joints), v, duration)
    header, decoded = sm.decode(sm.encode_traj_pt(point))
    assert header == sm.Header(sm.JOINT_TRAJ_PT, sm.SERVICE_REQUEST, sm.INVALID)
    assert decoded.sequence == seq
    assert decoded.joints_rad.tolist() == joints
    assert (decoded.velocity, decoded.duration_s) == (v, duration)


@given(JOINTS, st.lists(INT32, min_size=7, max_size=7))
def test_state_messages_survive_encode_and_decode_exactly(joints, status_fields):
    _, q = sm.decode(sm.encode_joint_position(np.array(joints)))
    assert q.tolist() == joints
    status = sm.RobotStatus(*status_fields)
    assert sm.decode(sm.encode_status(status)) == (
        sm.Header(sm.STATUS, sm.TOPIC, sm.INVALID),
        status,
    )


@given(st.integers(0, 7), NON_FINITE | BEYOND_FLOAT32)
def test_a_value_the_wire_cannot_carry_is_refused_naming_its_field(slot, bad):
    """Slots 0-5: a joint; 6: the velocity; 7: the duration."""
    values = [0.1] * 8
    values[slot] = bad
    point = sm.JointTrajPt(3, np.array(values[:6]), values[6], values[7])
    field = f"joints\\[{slot}\\]" if slot < 6 else ("velocity", "duration")[slot - 6]
    with pytest.raises(sm.ProtocolError, match=f"^{field}: .* is not a finite float32"):
        sm.encode_traj_pt(point)
    if slot < 6:
        with pytest.raises(sm.ProtocolError, match=f"^{field}: "):
            sm.encode_joint_position(np.array(values[:6]))


@given(st.integers(0, 11), NON_FINITE)
def test_a_received_nan_or_infinity_is_refused_naming_its_field(slot, bad):
    """Slots 0-9 of the joints (the unused four included), 10: velocity, 11: duration."""
    values = [0.0] * 12
    values[slot] = bad
    body = sm.JOINT_TRAJ_PT_BODY.pack(1, *values)
    field = f"joints\\[{slot}\\]" if slot < 10 else ("velocity", "duration")[slot - 10]
    with pytest.raises(sm.ProtocolError, match=f"^{field}: {bad!r} is not a finite number"):
        sm.decode_traj_pt(body)


def test_a_sequence_beyond_int32_is_refused():
    with pytest.raises(sm.ProtocolError, match="sequence: 2147483648 is not an int32"):
        sm.encode_traj_pt(sm.JointTrajPt(2**31, np.zeros(6), 0.5))
