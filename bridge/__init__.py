"""Bridges between covswarm and other robot stacks.

``covswarm.bridge.rmw_zenoh`` (ROS 2's Zenoh wire conventions) and ``covswarm.bridge.cdr``
(message payloads) are the wire layer, ``covswarm.bridge.brain`` and
``covswarm.bridge.mission_view`` the sans-IO state, ``covswarm.bridge.process`` the Zenoh
shell and the ``covswarm bridge ros2`` command.
"""
