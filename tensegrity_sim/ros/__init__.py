"""The ROS 2 side of tensegrity_sim: the node, its MCAP logs and their replay.

Split the way ROS packages are best split, so that everything but the wiring runs and is tested without
ROS installed:

* :mod:`.messages` — the one source of ROS 2 Jazzy message classes: rclpy's where it is importable,
  otherwise the same types from rosbags' Jazzy type store (same fields, same CDR bytes).
* :mod:`.node_logic` — the whole behaviour of the node (input validation, real-time scheduling on an
  injected clock, publish decimation, impulse summing, contact queueing, services, output messages),
  with no rclpy and no transport: inputs come in as message objects, outputs leave through a callback.
* :mod:`.cdr` — CDR bytes of the high-rate outputs written straight from numpy arrays (templates whose
  layout comes from the type store), for the log and for transports that send raw CDR.
* :mod:`.log` — MCAP logs (profile ``ros2``, CDR, ``ros2msg`` schemas) that ``ros2 bag info`` and
  Foxglove open, with the scene and settings embedded.
* :mod:`.replay` — re-simulate a log and check it bit for bit; summarise a log.
* :mod:`.rclpy_node` — the thin rclpy node (the only module that imports rclpy).

Nothing here is imported by the numerical core; importing this package imports nothing heavy.
"""
