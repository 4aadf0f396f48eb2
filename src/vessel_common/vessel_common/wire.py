"""Messages on the wire through rosbags' generated CDR code, not rclpy's message objects.

rclpy turns every received message into its generated Python classes field by field (each nested message is first
built with its defaults through property setters, then replaced) and converts it back the same way on publish. For
an array of tens of tracks, that conversion is most of what the tracker, the fuser and the GPS publisher spend per
image. rosbags generates, per message type, plain Python that reads and writes the CDR bytes straight into
dataclasses with the same field names. It is the same CDR (rclpy reads it back as the same message, and the other
way round), so every other node, the recorder and a consumer still use the ordinary message classes.

A node subscribes with ``raw=True`` and decodes with ``WireType.decode``, builds its output with
``WireType.new`` (or edits what it decoded), and publishes the bytes of ``WireType.encode``. Fixed-size numeric
arrays are numpy arrays of their element type, as rclpy gives them.
"""

from __future__ import annotations

import functools
import struct

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError

from vessel_common.errors import DataError
from vessel_common.message_types import require_type, typestore

_NUMPY_TYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
                "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64,
                "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


class WireType:
    """One message type's CDR decoding, encoding and zero-valued construction (e.g. ``vessel_msgs/msg/Track``)."""

    def __init__(self, msgtype: str):
        self.msgtype = msgtype
        self._store = typestore()
        require_type(self._store, msgtype)

    def decode(self, cdr: bytes) -> object:
        """The message of serialised ``cdr`` (as a raw subscription receives it); DataError if it is not one."""
        try:
            return self._store.deserialize_cdr(cdr, self.msgtype)
        except (SerdeError, struct.error, ValueError, TypeError) as error:
            raise DataError(f"a {self.msgtype} message that cannot be decoded ({len(cdr)} bytes): {error}; the "
                            "publisher's message definition differs from this build's vessel_msgs") from None

    def encode(self, msg: object) -> bytes:
        """The CDR bytes of ``msg`` (for ``Publisher.publish``); DataError naming the type if a field is wrong."""
        try:
            return bytes(self._store.serialize_cdr(msg, self.msgtype))
        except (SerdeError, struct.error, AttributeError, TypeError, ValueError, AssertionError) as error:
            raise DataError(f"a {self.msgtype} message with a field of the wrong type or length: {error}") from None

    def new(self, **fields) -> object:
        """A message with ``fields`` set and every other field zero, empty or all-zero (as a default rclpy one)."""
        return _maker(self._store, self.msgtype)(fields)


@functools.cache
def _maker(store, msgtype: str):
    """A function ``fields -> message`` of ``msgtype``: the field defaults worked out once, not at every message."""
    defaults = [(name, _default_maker(store, desc)) for name, desc in store.fielddefs[msgtype][1]]
    names = frozenset(name for name, _ in defaults)
    cls = store.types[msgtype]

    def make(fields: dict) -> object:
        if not names.issuperset(fields):
            raise DataError(f"{msgtype} has no field {', '.join(sorted(set(fields) - names))}")
        return cls(**{name: fields[name] if name in fields else default() for name, default in defaults})

    return make


def _default_maker(store, desc):
    """A function giving a field's default: a new message or array each time, the same immutable value otherwise."""
    kind, detail = desc
    if kind == Nodetype.NAME:
        nested = _maker(store, detail)
        return lambda: nested({})
    if kind == Nodetype.BASE:
        name = detail[0]
        value = "" if name in ("string", "wstring") else False if name == "bool" else 0.0 if "float" in name else 0
        return lambda: value
    (element_kind, element), length = detail
    count = length if kind == Nodetype.ARRAY else 0
    if element_kind == Nodetype.BASE and element[0] in _NUMPY_TYPES:
        dtype = _NUMPY_TYPES[element[0]]
        return lambda: np.zeros(count, dtype=dtype)
    element_default = _default_maker(store, (element_kind, element))
    return lambda: [element_default() for _ in range(count)]


def decoding_callback(wire: WireType, on_message, health) -> object:
    """A raw subscription's callback: ``on_message(decoded)``; a message that cannot be decoded is counted, logged.

    ``health``: the node's ``NodeHealth`` (its problem kind ``undecodable_message``).
    """
    def on_cdr(cdr: bytes) -> None:
        try:
            msg = wire.decode(cdr)
        except DataError as error:
            health.problem("undecodable_message", f"{error}: dropped")
            return
        on_message(msg)

    return on_cdr


def encoded_or_none(wire: WireType, msg: object, health) -> bytes | None:
    """``wire.encode(msg)``, or None after counting and logging why it cannot be encoded (``unencodable_message``)."""
    try:
        return wire.encode(msg)
    except DataError as error:
        health.problem("unencodable_message", f"{error}: not published")
        return None
