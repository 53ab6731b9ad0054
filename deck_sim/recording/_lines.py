"""Protobuf encoding, with numpy, of the messages a recorder writes at every step: ``foxglove.SceneUpdate`` of
line strips (predictions, the agent's path) and ``foxglove.FrameTransforms``.

Building one foxglove-sdk object per point and per vector costs more than everything else a step records (a step
logs about a hundred points). Here points and poses are encoded in one numpy operation into the protobuf wire
format, what never changes (frame names, ids, colours) is encoded once, and messages are assembled from bytes.
The result is byte for byte what foxglove-sdk's own encoder writes (tested), except that a number equal to zero is
written explicitly (the SDK omits it, as protobuf allows); both decode to the same values, and a negative zero
keeps its sign here.

Field numbers follow the foxglove schemas: SceneUpdate.entities = 2; SceneEntity: timestamp = 1, frame_id = 2,
id = 3, lines = 11; LinePrimitive: pose = 2, thickness = 3, points = 5, color = 6; Point3 and Vector3: x, y, z =
1, 2, 3; FrameTransforms.transforms = 1; FrameTransform: timestamp = 1, parent_frame_id = 2, child_frame_id = 3,
translation = 4, rotation = 5; Quaternion: x, y, z, w = 1, 2, 3, 4; Timestamp: seconds = 1, nanos = 2.
"""

from __future__ import annotations

import struct

import numpy as np

_POINT = np.dtype(
    [("tag", "u1"), ("len", "u1"), ("tx", "u1"), ("x", "<f8"), ("ty", "u1"), ("y", "<f8"), ("tz", "u1"), ("z", "<f8")]
)
"""One LinePrimitive.points field holding a Point3: 29 bytes (numpy packs the fields)."""
_POSE = np.dtype(
    [("tt", "u1"), ("tl", "u1"), ("tx", "u1"), ("x", "<f8"), ("ty", "u1"), ("y", "<f8"), ("tz", "u1"), ("z", "<f8")]
    + [("rt", "u1"), ("rl", "u1"), ("qxt", "u1"), ("qx", "<f8"), ("qyt", "u1"), ("qy", "<f8")]
    + [("qzt", "u1"), ("qz", "<f8"), ("qwt", "u1"), ("qw", "<f8")]
)
"""FrameTransform.translation (Vector3) and .rotation (Quaternion) fields: 67 bytes."""
_LEN, _FIXED64, _VARINT = 2, 1, 0


_ONE_BYTE = [bytes((i,)) for i in range(128)]


def _varint(n: int) -> bytes:
    if n < 128:
        return _ONE_BYTE[n]
    out = bytearray()
    while n >= 128:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _tag(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _field(field: int, payload: bytes) -> bytes:
    """A length-delimited field (message, string, bytes)."""
    return _tag(field, _LEN) + _varint(len(payload)) + payload


_TIMESTAMP = _tag(1, _LEN)  # SceneEntity.timestamp
_LINES = _tag(11, _LEN)  # SceneEntity.lines
_ENTITIES = _tag(2, _LEN)  # SceneUpdate.entities
_TRANSFORMS = _tag(1, _LEN)  # FrameTransforms.transforms


def points(xyz: np.ndarray) -> bytes:
    """The ``points`` fields of a LinePrimitive for points (k, 3), metres."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    rec = np.empty(len(xyz), dtype=_POINT)
    rec["tag"], rec["len"] = 5 << 3 | _LEN, 27
    rec["tx"], rec["ty"], rec["tz"] = 1 << 3 | _FIXED64, 2 << 3 | _FIXED64, 3 << 3 | _FIXED64
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return rec.tobytes()


def timestamp(t_ns: int) -> bytes:
    """A google.protobuf.Timestamp message (fields equal to zero omitted)."""
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    out = b""
    if sec:
        out += _tag(1, _VARINT) + _varint(sec)
    if nsec:
        out += _tag(2, _VARINT) + _varint(nsec)
    return out


def stamp(t_ns: int) -> bytes:
    """The ``timestamp`` field (number 1) of a SceneEntity or FrameTransform at ``t_ns`` nanoseconds."""
    ts = timestamp(t_ns)
    return _TIMESTAMP + _varint(len(ts)) + ts


class LineStrips:
    """Encodes SceneUpdates of entities that each hold one LINE_STRIP; what never changes is encoded once.

    Args:
        frame_id: Frame of every entity.
        ids: Entity ids, in the order ``encode`` receives their points.
        pose: The encoded foxglove Pose of every line (e.g. ``Pose(...).encode()``).
        thickness: Line width, metres (not scale invariant).
        color: The encoded foxglove Color of every line.
    """

    def __init__(self, frame_id: str, ids: list[str], pose: bytes, thickness: float, color: bytes) -> None:
        frame = _field(2, frame_id.encode())
        self._heads = [frame + _field(3, ident.encode()) for ident in ids]
        # LinePrimitive: type LINE_STRIP (0, the default, so not written), pose, thickness, points, color
        self._line_head = _field(2, pose) + (_tag(3, _FIXED64) + struct.pack("<d", thickness) if thickness else b"")
        self._line_tail = _field(6, color)

    def encode(self, stamp: bytes, point_fields: list[bytes]) -> bytes:
        """The SceneUpdate whose entity i draws ``point_fields[i]`` (from ``points``); ``stamp`` is the entities'
        timestamp field (``stamp``)."""
        out = []
        for head, pts in zip(self._heads, point_fields, strict=True):
            line = self._line_head + pts + self._line_tail
            ent = stamp + head + _LINES + _varint(len(line)) + line
            out.append(_ENTITIES + _varint(len(ent)) + ent)
        return b"".join(out)


class Transforms:
    """Encodes FrameTransforms from one parent frame to fixed child frames; names are encoded once.

    Args:
        parent: The parent frame.
        children: The child frames, in the order ``encode`` receives their poses.
    """

    def __init__(self, parent: str, children: list[str]) -> None:
        parent_field = _field(2, parent.encode())
        self._heads = [parent_field + _field(3, child.encode()) for child in children]

    def encode(self, stamp: bytes, poses: np.ndarray) -> bytes:
        """The FrameTransforms for poses (k, 7): x, y, z (m), then the quaternion w, x, y, z; ``stamp`` is the
        transforms' timestamp field (``stamp``)."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 7)
        rec = np.empty(len(poses), dtype=_POSE)
        rec["tt"], rec["tl"], rec["rt"], rec["rl"] = 4 << 3 | _LEN, 27, 5 << 3 | _LEN, 36
        rec["tx"] = rec["qxt"] = 1 << 3 | _FIXED64
        rec["ty"] = rec["qyt"] = 2 << 3 | _FIXED64
        rec["tz"] = rec["qzt"] = 3 << 3 | _FIXED64
        rec["qwt"] = 4 << 3 | _FIXED64
        rec["x"], rec["y"], rec["z"] = poses[:, 0], poses[:, 1], poses[:, 2]
        rec["qw"], rec["qx"], rec["qy"], rec["qz"] = poses[:, 3], poses[:, 4], poses[:, 5], poses[:, 6]
        vectors = rec.tobytes()
        out = []
        size = _POSE.itemsize
        for i, head in enumerate(self._heads):
            body = stamp + head + vectors[i * size : (i + 1) * size]
            out.append(_TRANSFORMS + _varint(len(body)) + body)
        return b"".join(out)
