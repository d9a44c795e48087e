"""A ROS 2 node that tracks a gyro pair's calibration live: drop this file into a ROS 2 Python package.

It subscribes to two ``sensor_msgs/msg/Imu`` topics (``imu1_topic``: gyro 1, the reference; ``imu2_topic``) and
publishes the tracked state and the step alarms as JSON text on ``~/state`` (``std_msgs/msg/String``), the same
lines as ``gyrocal track``. The logic (:class:`GyroPairNodeLogic`) knows nothing of ``rclpy``: it takes messages
with ``header.stamp`` and ``angular_velocity`` and a ``publish(str)`` callable, so it is tested without ROS
(``tests/test_live.py``); ``rclpy`` (from a ROS 2 installation, it is not on PyPI) is imported only by
:func:`main`.

Run: ``ros2 run <your_package> gyro_pair_tracker --ros-args -p imu1_topic:=/imu0 -p imu2_topic:=/imu1`` (after
adding ``gyro_pair_tracker = <your_package>.ros2_node:main`` to the package's ``console_scripts``), or
``python3 ros2_node.py --ros-args -p imu1_topic:=/imu0 -p imu2_topic:=/imu1`` with ROS 2 sourced and
``pip install "fusion_gyrocal[track]"``.
"""

from __future__ import annotations

import json

from fusion_gyrocal.online.live import LivePair


class GyroPairNodeLogic:
    """The node without ROS: IMU messages in, JSON lines out through ``publish``.

    Parameters
    ----------
    publish : callable(str)
        Called with each JSON line (``{"type": "seeded" | "alarm" | "reseed" | "state" | "final", ...}``).
    every_s : float
        A state line every ``every_s`` seconds of message time.
    **live_options
        :class:`fusion_gyrocal.online.live.LivePair` options (``seed_s``, ``tracker``, ``mode``, ``window_s``, ...).
    """

    def __init__(self, publish, *, every_s: float = 1.0, **live_options):
        self.publish, self.every_s = publish, float(every_s)
        self.live = LivePair(**live_options)
        self._next_t = None

    def _emit(self, obj) -> None:
        self.publish(json.dumps(obj))

    def on_imu(self, gyro: int, msg) -> None:
        """One ``sensor_msgs/msg/Imu`` of gyro 1 or 2 (its ``header.stamp`` is the sample time)."""
        st, w = msg.header.stamp, msg.angular_velocity
        t = int(st.sec) + int(st.nanosec) * 1e-9
        for event in self.live.push(gyro, t, (w.x, w.y, w.z)):
            self._emit(event)
        tr = self.live.tracker
        if tr is not None and tr.n_samples and (self._next_t is None or tr.t >= self._next_t):
            self._emit(self.live.state())
            self._next_t = tr.t + self.every_s

    def finish(self) -> None:
        """At shutdown: the samples held back reach the tracker, and a final state line is published."""
        for event in self.live.close():
            self._emit(event)
        self._emit({**self.live.state(), "type": "final"})


def main(args=None) -> None:
    """The ``rclpy`` node around :class:`GyroPairNodeLogic` (needs a ROS 2 installation)."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu
    from std_msgs.msg import String

    rclpy.init(args=args)
    node = Node("gyro_pair_tracker")
    p = {name: node.declare_parameter(name, default).value for name, default in
         (("imu1_topic", "/imu0"), ("imu2_topic", "/imu1"), ("seed_s", 30.0), ("every_s", 1.0))}
    pub = node.create_publisher(String, "~/state", 10)
    logic = GyroPairNodeLogic(lambda text: pub.publish(String(data=text)), every_s=p["every_s"], seed_s=p["seed_s"])
    node.create_subscription(Imu, p["imu1_topic"], lambda m: logic.on_imu(1, m), qos_profile_sensor_data)
    node.create_subscription(Imu, p["imu2_topic"], lambda m: logic.on_imu(2, m), qos_profile_sensor_data)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        logic.finish()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
