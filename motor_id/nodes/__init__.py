"""ROS 2 nodes: the only package that imports rclpy.

Every node process enters through this package (``ros2 run motor_id driver``, the console
scripts, ``python -m motor_id.nodes.identifier``), so it limits BLAS to one thread here,
before the node's module loads numpy (:func:`motor_id.blas.limit_threads`).
"""

from motor_id.blas import limit_threads

limit_threads()
