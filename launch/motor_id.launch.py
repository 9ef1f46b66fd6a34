"""One motor: the driver and the identifier in a namespace, with their parameter files.

    ros2 launch motor_id motor_id.launch.py namespace:=left device:=/dev/ttyACM0

Topic names of both nodes are relative (``samples``, ``voltage``, ``~/estimate``...), so
a namespace keeps two motors apart; ``/diagnostics`` stays global.

Both nodes are tied to the launch process (:mod:`motor_id.lifeline`, through each
node's ``prefix``): whatever ends ``ros2 launch`` (Ctrl-C, SIGTERM, a SIGHUP when its
terminal closes, SIGKILL), the nodes get SIGTERM and stop as on Ctrl-C (the driver
commands 0 V and closes its recording) instead of running on, orphaned.
"""

import os
import shlex

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

from motor_id.lifeline import launcher_prefix

CONFIG = PathJoinSubstitution([FindPackageShare('motor_id'), 'config'])


def generate_launch_description():
    """Arguments: namespace, device, joint, driver_params, identifier_params."""
    namespace = LaunchConfiguration('namespace')
    device = LaunchConfiguration('device')
    joint = LaunchConfiguration('joint')
    driver_params = LaunchConfiguration('driver_params')
    identifier_params = LaunchConfiguration('identifier_params')
    tied = shlex.join(launcher_prefix(os.getpid()))   # this is the launch process
    return LaunchDescription([
        DeclareLaunchArgument('namespace', default_value='',
                              description='namespace of this motor (e.g. left)'),
        DeclareLaunchArgument('device', default_value='/dev/ttyACM0',
                              description='card device path or pyserial URL; also the '
                                          "identifier's hardware_id"),
        DeclareLaunchArgument('joint', default_value='',
                              description='JointState joint for the identifier with '
                                          'input: topics (empty: the only one)'),
        DeclareLaunchArgument('driver_params',
                              default_value=PathJoinSubstitution([CONFIG, 'driver.yaml']),
                              description='parameter file of the driver'),
        DeclareLaunchArgument('identifier_params',
                              default_value=PathJoinSubstitution([CONFIG, 'identifier.yaml']),
                              description='parameter file of the identifier'),
        Node(package='motor_id', executable='driver', name='driver', namespace=namespace,
             parameters=[driver_params, {'device': device}], output='screen', prefix=tied),
        Node(package='motor_id', executable='identifier', name='identifier',
             namespace=namespace,
             parameters=[identifier_params, {'hardware_id': device, 'joint_name': joint}],
             output='screen', prefix=tied),
    ])
