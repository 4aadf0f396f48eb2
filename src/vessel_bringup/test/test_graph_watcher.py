"""What the graph watcher reads from serialised messages."""

from __future__ import annotations

import struct

from vessel_bringup import graph_watcher


def test_header_stamp_is_read_from_serialised_messages_of_either_byte_order():
    little = b"\x00\x01\x00\x00" + struct.pack("<iI", 1601495752, 884000000) + b"rest"
    big = b"\x00\x00\x00\x00" + struct.pack(">iI", 1601495752, 884000000) + b"rest"
    assert graph_watcher.header_stamp_ns(little) == 1601495752_884000000
    assert graph_watcher.header_stamp_ns(big) == 1601495752_884000000
