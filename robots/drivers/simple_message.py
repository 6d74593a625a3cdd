"""ROS-Industrial "simple_message": the byte format the Staubli VAL 3 server speaks.

Sources (read, not guessed): `industrial_core/simple_message` (simple_message.h: message types,
comm types, reply codes; joint_traj_pt.h: the special sequence numbers; robot_status.h: the
tri-state and mode values) and `staubli_val3_driver/val3/ros_server` (setupRosMsgs: the fixed
lengths; decTrajPt / encTrajPtAck / encodeJState / encodeStatus: the body layouts; recvData:
the server reads an exact byte count per field; sendRosMsg: it writes prefix, header and body
as three separate writes).

A packet is `int32 length | int32 msg_type | int32 comm_type | int32 reply_code | body`,
little-endian, `length` counting the bytes after itself; reals are float32. The VAL 3 server
reads a 4-byte prefix and a 12-byte header, then a body of the size its message type has; it
has no body size for any other type, so an unknown message (even a PING) leaves its body in the
stream to be read as the next header: never send anything but JOINT_TRAJ_PT to it.

Every real in either direction must be a finite float32: a NaN or an infinity is refused with a
ProtocolError naming the field, when encoding and when decoding (a NaN joint reading compares
false with every tolerance, so a check written `deviation > tolerance` would let it pass), and so
is a value beyond float32's range, which the wire would turn into an infinity.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import time
from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

# simple_message.h: StandardMsgTypes, CommTypes, ReplyTypes
PING = 1
JOINT_POSITION = 10
JOINT_TRAJ_PT = 11
STATUS = 13
TOPIC = 1
SERVICE_REQUEST = 2
SERVICE_REPLY = 3
INVALID = 0
SUCCESS = 1
FAILURE = 2
# joint_traj_pt.h: SpecialSeqValues
STOP_TRAJECTORY = -4
# Ten joint slots on the wire (J1-J6 first, the rest zero for a 6-axis arm).
WIRE_JOINTS = 10

PREFIX = struct.Struct("<i")
HEADER = struct.Struct("<iii")
# Body sizes from setupRosMsgs (prefix length minus the 12-byte header).
JOINT_TRAJ_PT_BODY = struct.Struct("<i10fff")  # sequence, joints[10], velocity, duration
JOINT_POSITION_BODY = struct.Struct("<i10f")  # sequence, joints[10]
STATUS_BODY = struct.Struct("<7i")  # drives_powered .. motion_possible
BODY_SIZES = {
    JOINT_TRAJ_PT: JOINT_TRAJ_PT_BODY.size,
    JOINT_POSITION: JOINT_POSITION_BODY.size,
    STATUS: STATUS_BODY.size,
}


# The largest finite float32 (IEEE 754 binary32), the reals' type on the wire.
FLOAT32_MAX = float(np.finfo(np.float32).max)
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


class ProtocolError(Exception):
    """Bytes that are not the message the protocol has there, or values no message can carry."""


@dataclass(frozen=True)
class Header:
    msg_type: int
    comm_type: int
    reply_code: int


@dataclass(frozen=True, eq=False)
class JointTrajPt:
    """A point the controller moves to: joints (rad, six), velocity as a fraction of each
    joint's nominal speed (the VAL 3 server multiplies by 100 for movej's percent), duration
    (carried, ignored by that server). sequence STOP_TRAJECTORY stops and clears the queue."""

    sequence: int
    joints_rad: np.ndarray
    velocity: float
    duration_s: float = 0.0


@dataclass(frozen=True)
class RobotStatus:
    """The STATUS message's tri-states: -1 unknown, 0 false, 1 true (mode: -1 unknown,
    1 manual, 2 auto; error_code: the first failed server task's status)."""

    drives_powered: int
    e_stopped: int
    error_code: int
    in_error: int
    in_motion: int
    mode: int
    motion_possible: int

    def refusal(self) -> str | None:
        """Why motion must not be commanded now, or None."""
        if self.e_stopped == 1:
            return "the controller reports an emergency stop"
        if self.drives_powered != 1:
            return "the arm's drives are not powered"
        if self.in_error == 1:
            return f"the controller reports an error (code {self.error_code})"
        if self.motion_possible != 1:
            return "the controller reports that motion is not possible"
        return None


def _wire_real(field: str, value: float) -> float:
    """`value` as the wire can carry it; ProtocolError naming `field` otherwise."""
    value = float(value)
    if not abs(value) <= FLOAT32_MAX:  # false for NaN too
        raise ProtocolError(f"{field}: {value!r} is not a finite float32")
    return value


def _wire_int(field: str, value: int) -> int:
    if not INT32_MIN <= value <= INT32_MAX:
        raise ProtocolError(f"{field}: {value!r} is not an int32")
    return value


def _wire_joints(joints_rad: np.ndarray) -> list[float]:
    q = np.asarray(joints_rad, float).ravel()
    if len(q) > WIRE_JOINTS:
        raise ProtocolError(f"joints: at most {WIRE_JOINTS} fit a message, got {len(q)}")
    values = [_wire_real(f"joints[{i}]", x) for i, x in enumerate(q)]
    return values + [0.0] * (WIRE_JOINTS - len(q))


def _finite(field: str, values: tuple[float, ...]) -> None:
    """Decoded float32 reals: ProtocolError naming the first that is NaN or infinite."""
    for i, value in enumerate(values):
        if not math.isfinite(value):
            name = field if len(values) == 1 else f"{field}[{i}]"
            raise ProtocolError(f"{name}: {value!r} is not a finite number")


def packet(header: Header, body: bytes) -> bytes:
    return (
        PREFIX.pack(HEADER.size + len(body))
        + HEADER.pack(header.msg_type, header.comm_type, header.reply_code)
        + body
    )


def encode_traj_pt(point: JointTrajPt) -> bytes:
    """A JOINT_TRAJ_PT service request, as the motion port reads it."""
    body = JOINT_TRAJ_PT_BODY.pack(
        _wire_int("sequence", point.sequence),
        *_wire_joints(point.joints_rad),
        _wire_real("velocity", point.velocity),
        _wire_real("duration", point.duration_s),
    )
    return packet(Header(JOINT_TRAJ_PT, SERVICE_REQUEST, INVALID), body)


def encode_traj_pt_reply(sequence: int, reply_code: int) -> bytes:
    """The server's reply (encTrajPtAck): the sequence echoed, every other body field zero."""
    body = JOINT_TRAJ_PT_BODY.pack(sequence, *([0.0] * WIRE_JOINTS), 0.0, 0.0)
    return packet(Header(JOINT_TRAJ_PT, SERVICE_REPLY, reply_code), body)


def encode_joint_position(joints_rad: np.ndarray, sequence: int = 0) -> bytes:
    """The state port's JOINT_POSITION topic (encodeJState; the server never counts sequence)."""
    body = JOINT_POSITION_BODY.pack(sequence, *_wire_joints(joints_rad))
    return packet(Header(JOINT_POSITION, TOPIC, INVALID), body)


def encode_status(status: RobotStatus) -> bytes:
    body = STATUS_BODY.pack(
        status.drives_powered,
        status.e_stopped,
        status.error_code,
        status.in_error,
        status.in_motion,
        status.mode,
        status.motion_possible,
    )
    return packet(Header(STATUS, TOPIC, INVALID), body)


def _unpack(layout: struct.Struct, body: bytes, what: str) -> tuple:
    if len(body) != layout.size:
        raise ProtocolError(f"{what}: a body of {layout.size} bytes, got {len(body)}")
    return layout.unpack(body)


def decode_traj_pt(body: bytes, joints: int = 6, finite: bool = True) -> JointTrajPt:
    """A JOINT_TRAJ_PT body; every slot of the ten joints, velocity and duration finite
    (finite=False: any float32, as the VAL 3 server reads it, for its emulator)."""
    values = _unpack(JOINT_TRAJ_PT_BODY, body, "JOINT_TRAJ_PT")
    if finite:
        _finite("joints", values[1:11])
        _finite("velocity", values[11:12])
        _finite("duration", values[12:13])
    return JointTrajPt(values[0], np.array(values[1 : 1 + joints], float), values[11], values[12])


def decode_joint_position(body: bytes, joints: int = 6) -> np.ndarray:
    """A JOINT_POSITION body's joints (rad); every slot of the ten finite."""
    values = _unpack(JOINT_POSITION_BODY, body, "JOINT_POSITION")
    _finite("joints", values[1:])
    return np.array(values[1 : 1 + joints], float)


def decode_status(body: bytes) -> RobotStatus:
    return RobotStatus(*_unpack(STATUS_BODY, body, "STATUS"))


DECODERS = {
    JOINT_TRAJ_PT: decode_traj_pt,
    JOINT_POSITION: decode_joint_position,
    STATUS: decode_status,
}


def _check_frame(length: int, header: Header, expected: Collection[int]) -> int:
    """The body size of a packet announced by `length` and `header`, if it is one of `expected`
    with the length its type has (a peer speaking another protocol fails here, not later with
    garbage joint values)."""
    size = BODY_SIZES.get(header.msg_type)
    if header.msg_type not in expected or size is None or length != HEADER.size + size:
        raise ProtocolError(
            f"expected a simple_message of type {sorted(expected)}, got type "
            f"{header.msg_type} with length {length}"
        )
    return size


def decode(data: bytes, expected: Collection[int] = tuple(DECODERS)) -> tuple[Header, object]:
    """One whole packet held in `data`: its header and its decoded body (a JointTrajPt, the
    joints of a JOINT_POSITION, a RobotStatus); ProtocolError for any other bytes."""
    start = PREFIX.size + HEADER.size
    if len(data) < start:
        raise ProtocolError(f"a packet has at least {start} bytes, got {len(data)}")
    (length,) = PREFIX.unpack_from(data)
    header = Header(*HEADER.unpack_from(data, PREFIX.size))
    size = _check_frame(length, header, expected)
    if len(data) != start + size:
        raise ProtocolError(f"a packet of {start + size} bytes, got {len(data)}")
    return header, DECODERS[header.msg_type](data[start:])


def recv_exact(sock: socket.socket, count: int, deadline_s: float | None = None) -> bytes:
    """Exactly `count` bytes however TCP split them; ConnectionError when the peer closed,
    TimeoutError when they have not all come by `deadline_s` (monotonic; None: the socket's own
    timeout for each read), so a peer sending a byte at a time cannot stretch the wait."""
    chunks, got = [], 0
    while got < count:
        if deadline_s is not None:
            left_s = deadline_s - time.monotonic()
            if left_s <= 0:
                raise TimeoutError(f"{got} of {count} bytes by the deadline")
            sock.settimeout(left_s)
        chunk = sock.recv(count - got)
        if not chunk:
            raise ConnectionError("the connection was closed by the other end")
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def read_packet(
    sock: socket.socket, expected: set[int], deadline_s: float | None = None
) -> tuple[Header, bytes]:
    """One whole packet of a type in `expected`, its length checked against the type's size;
    the body is left to the type's decoder."""
    (length,) = PREFIX.unpack(recv_exact(sock, PREFIX.size, deadline_s))
    header = Header(*HEADER.unpack(recv_exact(sock, HEADER.size, deadline_s)))
    size = _check_frame(length, header, expected)
    return header, recv_exact(sock, size, deadline_s)


def close_socket(sock: socket.socket) -> None:
    """Shut down (which wakes a thread blocked on it) and close; errors of a socket already gone
    are ignored."""
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()
