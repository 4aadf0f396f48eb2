"""Managed (lifecycle) nodes: transitions that call a node's phases, and publishers released outside them.

rclpy's ``LifecycleNode`` runs the transitions and gates its lifecycle publishers; a node of the project only says
what each phase makes and releases (``_configure``, ``_activate``, ``_deactivate``, ``_cleanup``).
"""

from __future__ import annotations

from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, TransitionCallbackReturn

from vessel_common.errors import VesselError


def release_publisher(node, publisher) -> None:
    """Destroy a publisher the node made, as a lifecycle publisher when it is one (so no transition touches it)."""
    if isinstance(node, LifecycleNode) and isinstance(publisher, LifecyclePublisher):
        node.destroy_lifecycle_publisher(publisher)
    else:
        node.destroy_publisher(publisher)


class PhasedLifecycle:
    """Lifecycle callbacks for a node whose work is split into phases, as ros2/demos lifecycle_py lays them out.

    The node defines ``_configure``, ``_activate``, ``_deactivate`` and ``_cleanup``; mix this in before
    ``rclpy.lifecycle.LifecycleNode``. A configure that fails with a ``VesselError`` (a missing model, a bad
    source) is logged and leaves the node unconfigured; shutdown works from any state.
    """

    def on_configure(self, state):
        """Make what the node needs (``_configure``); FAILURE, logged, when it cannot."""
        try:
            self._configure()
        except VesselError as error:
            self.get_logger().error(f"configure failed: {error}")
            self._cleanup()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        """Start the work (``_activate``); the lifecycle publishers start publishing."""
        self._activate()
        return super().on_activate(state)

    def on_deactivate(self, state):
        """Stop the work (``_deactivate``); what was configured stays."""
        self._deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        """Release what configure made (``_cleanup``)."""
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        """Stop and release everything, from any state."""
        self._deactivate()
        self._cleanup()
        return TransitionCallbackReturn.SUCCESS
