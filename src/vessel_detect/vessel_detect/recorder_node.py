"""Recorder node: writes chosen topics into a rosbag2 MCAP folder as they arrive.

It is a `ros2 bag record` for installs without the rosbag2 tools, writing the same format. Each topic is
subscribed once a publisher appears, with QoS adapted to what the publishers offer (so best-effort and latched
topics are recorded too) and the type taken from the parameter or from the graph. Messages are stored as
received (serialised CDR, no decode; ``/diagnostics`` only of its own graph's nodes); the log time is the
message's header stamp where it has one (so a replayed bag lines up with its source), else the receive time on the
node's clock (sim time under `use_sim_time`). A
message with no time yet (an unset stamp before the first `/clock` of a replay) is written at the next known
time, never at 1970, so a recording of a replay spans the replay's time only. On
SIGINT/SIGTERM the bag is closed properly: index, summary and metadata.yaml written, nothing received is lost.
Its parameters (``vessel_detect.parameter_tables.RECORDER_PARAMETERS``) are read-only: a restart changes them.
With a ``resume_file`` (the graph runners give one under respawn) a recorder restarted after a crash does not fail on
the bag its predecessor left: it records into the next part beside it, ``OUTPUT.1``, ``OUTPUT.2``, ... (the earlier
part stays as it is: ``./vessel bag recover OUTPUT`` makes it readable; ``resume_files.recording_parts`` lists them).

    ros2 run vessel_detect recorder --ros-args -p output:=out/run1 \
        -p topics:="['vessel/fix', 'vessel/tracks:vessel_msgs/msg/VesselTrackArray']"
"""

from __future__ import annotations

import struct
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from vessel_common.errors import DataError, VesselError
from vessel_common.graph_names import file_label, node_graph
from vessel_common.health import NodeHealth, steady_timer
from vessel_common.node_parameters import declare_table
from vessel_common.run import main_for
from vessel_detect import bag_messages, bag_topics, bag_writer
from vessel_detect.parameter_tables import RECORDER_DEFAULT_TOPICS, RECORDER_PARAMETERS
from vessel_detect.resume_files import (
    ResumeFileError,
    read_resume_file,
    recorder_output,
    recorder_record,
    write_json_atomically,
)
from vessel_detect.ros_messages import message_class

DEFAULT_TOPICS = list(RECORDER_DEFAULT_TOPICS)
"""The graph's outputs; `vessel/fixes` takes its type from the graph (it depends on the GPS publisher's mode)."""

_NS_PER_S = 1_000_000_000
_CDR_LITTLE_ENDIAN = (b"\x00\x01", b"\x00\x03")  # CDR_LE, PL_CDR_LE encapsulation ids


@dataclass
class TopicPlan:
    """A topic to record: its name, type (empty until known) and whether it starts with a std_msgs/Header."""

    name: str
    msgtype: str = ""
    has_header: bool = False
    subscribed: bool = False
    count: int = 0

    @property
    def bag_name(self) -> str:
        """The topic's name in the bag: a relative one without the graph's namespace (``bag_topics.in_bag``)."""
        return bag_topics.in_bag(self.name)


def parse_topic_entry(entry: str) -> TopicPlan:
    """`name` or `name:pkg/msg/Type` (or `pkg/Type`) -> TopicPlan; a name absolute (/diagnostics) or relative."""
    name, _, msgtype = entry.strip().partition(":")
    name = name.strip()
    if not name.strip("/") or " " in name or name.startswith("~"):
        raise DataError(f"topic entry {entry!r}: the topic must be a name like vessel/fix or /diagnostics")
    return TopicPlan(name, bag_messages.normalise_msgtype(msgtype) if msgtype.strip() else "")


def header_stamp_ns(cdr: bytes) -> int | None:
    """The header stamp of a serialised message whose first field is a std_msgs/Header (CDR: it leads)."""
    if len(cdr) < 12:
        return None
    fmt = "<iI" if cdr[:2] in _CDR_LITTLE_ENDIAN else ">iI"
    sec, nanosec = struct.unpack_from(fmt, cdr, 4)
    if sec <= 0 and nanosec == 0:
        return None  # an unset stamp says nothing about time
    return sec * _NS_PER_S + nanosec


def starts_with_header(msgtype: str) -> bool:
    """Whether the type's first field is a std_msgs/Header (rosbags type store)."""
    store = bag_messages.typestore()
    if msgtype not in store.fielddefs:
        return False
    fields = store.fielddefs[msgtype][1]
    return bool(fields) and fields[0][1][0].name == "NAME" and fields[0][1][1] == "std_msgs/msg/Header"


class RecorderNode(Node):
    """Record topics into a rosbag2 MCAP folder; see the module docstring."""

    def __init__(self) -> None:
        super().__init__("recorder")
        values = declare_table(self, RECORDER_PARAMETERS)  # all read-only: the bag is set up at start
        output, entries, self.overwrite = values["output"], values["topics"], values["overwrite"]
        self.discovery_period_s, self.depth = values["discovery_period_s"], values["queue_depth"]
        self.flush_period_s = values["flush_period_s"]
        self.plans = [parse_topic_entry(e) for e in entries if e.strip()]
        if not self.plans:
            raise DataError("parameter 'topics' is empty: name at least one topic to record")
        self.resume_file = Path(values["resume_file"]).expanduser() if values["resume_file"] else None
        self.health = NodeHealth(self, hardware_id="recorder")
        self.graph = node_graph(self.get_namespace())
        self.health.count("messages", 0)
        self.output, earlier = self._output_of(output)
        self.health.set_value("output", str(self.output))
        self.writer = bag_writer.BagWriter(
            self.output, overwrite=self.overwrite and not earlier, atomic=False, flush_every_s=self.flush_period_s,
            overwrite_hint="give another -p output:=..., or -p overwrite:=true to replace it").open()
        self.parts = [*earlier, self.output]
        self._note_parts()
        self.finished = False
        self._closed = False
        self._last_progress = time.monotonic()
        self._last_log_ns = 0
        self._untimed: list[tuple[TopicPlan, bytes]] = []
        steady_timer(self, self.discovery_period_s, self._discover)
        self._flushed = 0
        self._flush_timer = None
        if self.flush_period_s > 0:  # what came before a lull is on disk too, not only once the next message comes
            self._flush_timer = steady_timer(self, self.flush_period_s, self._flush)
        self._discover()
        self.get_logger().info(
            f"recording {', '.join(p.name for p in self.plans)} into {self.output} (SIGINT to stop and close)"
        )

    def _output_of(self, output: str) -> tuple[Path, list[Path]]:
        """The bag to write, and the earlier parts of this recording when this is a restart (its resume_file)."""
        try:
            data = read_resume_file(self.resume_file, "recorder") if self.resume_file is not None else None
            continued, earlier = recorder_output(data, output)
        except ResumeFileError as error:
            self.health.problem("resume_file_refused", f"{error}: recording as on a first start")
            continued, earlier = None, []
        if continued is not None:
            self.get_logger().info(
                f"a restart: continuing the recording {earlier[0]} into {continued} (the earlier part"
                f"{'s' if len(earlier) > 1 else ''} {', '.join(map(str, earlier))} stay as they are; `./vessel bag "
                "recover` makes one that was not closed readable)")
            return continued, earlier
        if not output:
            graph = file_label(self.graph)  # two cameras' recorders never share a bag
            output = f"rosbag2_{graph + '_' if graph else ''}{datetime.now(tz=UTC).strftime('%Y_%m_%d-%H_%M_%S')}"
        return Path(output).expanduser(), []

    def _note_parts(self) -> None:
        """Write the recording's parts to the resume file, so that a restarted recorder continues beside them."""
        if self.resume_file is None:
            return
        try:
            write_json_atomically(self.resume_file, recorder_record(self.parts))
        except OSError as error:
            self.health.problem("resume_file_unwritable", f"cannot write resume file {self.resume_file} "
                                f"({error.strerror or error}): a restarted recorder would refuse {self.output}")

    # ------------------------------------------------------------------------------------------------ discovery
    def _discover(self) -> None:
        for plan in self.plans:
            if plan.subscribed:
                continue
            infos = self.get_publishers_info_by_topic(plan.name)
            if not infos:
                continue
            try:
                self._subscribe(plan, infos)
            except VesselError as error:
                plan.subscribed = True  # do not retry every period
                self.health.problem("topic_unrecordable", f"cannot record {plan.name}: {error}")

    def _subscribe(self, plan: TopicPlan, infos) -> None:
        types = {bag_messages.normalise_msgtype(i.topic_type) for i in infos}
        if not plan.msgtype:
            if len(types) != 1:
                raise DataError(f"publishers disagree on the type ({', '.join(sorted(types))}); name it")
            plan.msgtype = types.pop()
        elif plan.msgtype not in types:
            raise DataError(f"configured as {plan.msgtype} but published as {', '.join(sorted(types))}")
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=self.depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        self.writer.add_topic(
            plan.bag_name, plan.msgtype, "latched" if latched else ("reliable" if reliable else "sensor_data")
        )
        plan.has_header = starts_with_header(plan.msgtype)
        self.create_subscription(
            message_class(plan.msgtype), plan.name, lambda cdr, p=plan: self._on_message(p, cdr), qos, raw=True
        )
        plan.subscribed = True
        self.get_logger().info(
            f"recording {plan.name} [{plan.msgtype}] ({'reliable' if reliable else 'best effort'}"
            f"{', transient local' if latched else ''})"
        )

    # ------------------------------------------------------------------------------------------------ messages
    def _on_message(self, plan: TopicPlan, cdr: bytes) -> None:
        if self._closed or (plan.msgtype == bag_topics.DIAGNOSTIC_ARRAY and not self._own_diagnostics(cdr)):
            return
        log_ns = header_stamp_ns(cdr) if plan.has_header else None
        if log_ns is None:
            log_ns = self.get_clock().now().nanoseconds
        if log_ns <= 0:  # no time yet: sim time before the replay's first /clock
            self.health.count("untimed_messages")
            if self._last_log_ns <= 0:
                self._untimed.append((plan, cdr))
                return
            log_ns = self._last_log_ns
        self._last_log_ns = max(self._last_log_ns, log_ns)
        for held_plan, held in self._untimed:
            self._write(held_plan, held, log_ns)
        self._untimed.clear()
        self._write(plan, cdr, log_ns)

    def _own_diagnostics(self, cdr: bytes) -> bool:
        """Whether a ``/diagnostics`` message reports a node of this recorder's graph (hot standbys included).

        ``/diagnostics`` is one topic for the whole domain: another camera's graph reports there too, in its own
        replay's time, and would spread this recording over that time.
        """
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.serialization import deserialize_message

        try:
            statuses = deserialize_message(cdr, DiagnosticArray).status
        except Exception:  # a damaged message: recorded as it came, like any other topic's
            return True
        return not statuses or any(node_graph(status.name.rpartition("/")[0]) == self.graph for status in statuses)

    def _write(self, plan: TopicPlan, cdr: bytes, log_ns: int) -> None:
        try:
            self.writer.write_cdr(plan.bag_name, cdr, log_ns)
        except VesselError as error:
            self.health.problem("write_failed", f"cannot write a message of {plan.name}: {error}")
            return
        plan.count += 1
        self.health.count("messages")
        if time.monotonic() - self._last_progress > 5.0:
            self._last_progress = time.monotonic()
            self.health.set_value("counts", ", ".join(f"{p.name}={p.count}" for p in self.plans if p.subscribed))

    def _flush(self) -> None:
        """Put what was written since the last flush on disk (a recorder killed then loses nothing of it)."""
        if self._closed or self.writer.message_count == self._flushed:
            return
        self._flushed = self.writer.message_count
        try:
            self.writer.flush()
        except OSError as error:
            self.health.problem("write_failed", f"cannot flush {self.output}: {error.strerror or error}")

    def close(self) -> None:
        """Finish the bag (called by run_node on SIGINT/SIGTERM and at shutdown)."""
        if self._closed:
            return
        self._closed = True
        if self._flush_timer is not None:  # no flush of a writer being closed, whatever wakes the executor next
            self._flush_timer.cancel()
        for plan, cdr in self._untimed:  # nothing ever gave them a time: the wall clock's
            self._write(plan, cdr, time.time_ns())
        self._untimed.clear()
        path = self.writer.close()
        counts = ", ".join(f"{p.name} {p.count}" for p in self.plans if p.count)
        never = [p.name for p in self.plans if not p.subscribed]
        summary = f"bag {path} closed: {self.writer.message_count} messages ({counts or 'none'})" + (
            f"; never published: {', '.join(never)}" if never else ""
        )
        if self.context.ok():
            self.get_logger().info(summary)
        else:  # after SIGINT the context is gone and the ROS logger can no longer reach /rosout
            print(f"[recorder] {summary}", file=sys.stderr, flush=True)


main = main_for(RecorderNode)

if __name__ == "__main__":
    main()
