"""What lets a node be restarted or replaced without losing its work: its state file and hot standby.

``NodeState`` resumes a node's core from its ``state_file`` at the first message and snapshots it as messages
come; ``Standby`` lets a second process run the same core as a discovered spare until it is promoted.
"""

from __future__ import annotations

import signal
import threading
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from vessel_common.errors import VesselError
from vessel_common.graph_names import node_graph
from vessel_common.health import NodeHealth
from vessel_common.parameter_declaration import declare_parameter
from vessel_common.state_file import STANDBY_DESCRIPTION, STATE_PARAMETERS, StateFile


def _declared(node: Node, name: str, default: Any, description: str, bounds=None) -> Any:
    """The value of a parameter the node's table has declared, else declared here (a node without a table)."""
    if node.has_parameter(name):
        return node.get_parameter(name).value
    return declare_parameter(node, name, default, description, **({"float_range": bounds} if bounds else {}))


class NodeState:
    """A node's ``state_file``: resume the core at the first message, snapshot it every ``state_period_s``.

    ``core`` has ``snapshot()`` (its state as plain data) and ``restore(state)``; the node's counters are saved with
    it, so a restarted node's /diagnostics carry on from where they were. Failures to write are counted
    (``state_not_saved``) and never stop the node; a file refused as not a snapshot of this node, schema and version
    is one warning (``state_file_refused``) and a cold start.
    """

    def __init__(self, node: Node, health: NodeHealth, kind: str, fingerprint: str, read_only: bool = False):
        values = {name: _declared(node, name, default, description, bounds)
                  for name, (default, description, bounds) in STATE_PARAMETERS.items()}
        self._node = node
        self._health = health
        self.read_only = read_only
        self.file = StateFile(values["state_file"], kind, fingerprint, values["state_period_s"],
                              values["state_max_age_s"], graph=node_graph(node.get_namespace())
                              ) if values["state_file"] else None

    def resume(self, stamp: float, core) -> bool:
        """At the first message after a start: restore ``core`` from the state file if it fits ``stamp``.

        True when the snapshot already holds the message stamped ``stamp`` (a hot standby reading the file its
        active node has just written): the caller skips it rather than apply it twice. ``read_only`` (a standby)
        reads the snapshot without marking it resumed, since it is the active node's.
        """
        if self.file is None or not self.file.pending or stamp <= 0.0:  # a zero stamp says nothing of the time
            return False
        state, what = self.file.resume(stamp, consume=not self.read_only)
        holds_this_message = False
        if state is not None:
            try:
                _restore(core, self._health, state)
            except (KeyError, TypeError, ValueError, AttributeError, VesselError) as error:
                what = self.file.refuse(f"it does not fit this node ({error})")
            else:
                self._health.count("resumed_from_state_file")
                holds_this_message = self.file.resumed_stamp == stamp
        if self.file.refused:
            self._health.problem("state_file_refused", what)
        else:
            self._node.get_logger().info(what)
        return holds_this_message

    def save(self, stamp: float, core) -> None:
        """Snapshot ``core`` if ``state_period_s`` of message time has passed since the last one."""
        if self.file is None or not self.file.due(stamp):
            return
        try:
            self.file.save(stamp, {"core": core.snapshot(), "counts": self._health.counts})
        except (OSError, VesselError) as error:
            self._health.problem("state_not_saved", f"the state file could not be written ({error}); a restart "
                                 "would start cold: check state_file's folder")


def _restore(core, health: NodeHealth, state) -> None:
    """The core as the snapshot holds it, and the counters the node had: its /diagnostics carry on, not from zero."""
    if not isinstance(state, dict) or set(state) != {"core", "counts"}:
        raise ValueError("a snapshot holds the node's core and its counters")
    core.restore(state["core"])
    health.restore_counts({str(kind): int(count) for kind, count in dict(state["counts"]).items()})


class Standby:
    """The ``standby`` parameter of a node that can wait as a hot spare of another process.

    A spare subscribes, runs its core on every message and is discovered by the rest of the graph like the
    active node, so promoting it costs no start-up and no discovery. Promotion is ``standby:=false`` (``ros2
    param set``) or SIGUSR1; the signal only raises a flag, acted on at the node's next message.
    """

    def __init__(self, node: Node):
        self._node = node
        self.active = not bool(_declared(node, "standby", False, STANDBY_DESCRIPTION))
        self._promotion_requested = False
        node.add_on_set_parameters_callback(self._on_set_parameters)
        if not self.active and threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGUSR1, self._on_signal)

    def _on_signal(self, signum, frame) -> None:
        self._promotion_requested = True

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name != "standby":
                continue
            if parameter.value and self.active:
                return SetParametersResult(successful=False, reason="a promoted node stays active: stop it instead")
            if not parameter.value and not self.active:
                self.active = True
                self._node.get_logger().info("promoted from standby: publishing from now on")
        return SetParametersResult(successful=True)

    def publishing(self) -> bool:
        """Whether to publish (and save state) now; carries out a promotion SIGUSR1 asked for."""
        if self._promotion_requested and not self.active:
            self._promotion_requested = False
            self._node.set_parameters([Parameter("standby", value=False)])
        return self.active
