"""Test support: generators and process harnesses for the tests, benchmarks and the demo.

As ``numpy.testing`` is to numpy: shipped with the package so that tests, benchmarks and
``motor-id demo`` import it by name, but nothing in the identification pipeline, the
nodes or the data readers imports it (``.importlinter`` puts it above the nodes).

recordings         the paper's experiment, simulated (``paper_recording``, ``SI_MOTOR``)
hidden             seeded hidden-effect cases on this package's own model
independent_sim    seeded cases on a second simulator written from the equations
independent_physics  that simulator's motor, joint, amplifier, integrator and sensors (numpy)
independent_kernel   its compiled event-located RK4 integrator (numba)
sim_joint          the simulated robot's joint: mechanisms, real-time stepping, truth
sim_robot          a simulated ros2_control robot (controller + joint_state_broadcaster)
procs              node processes and their ROS environment (no rclpy)
client             a threaded ROS client (rclpy) for scripts and tests
demo_client        the demo's client
ros                helpers of the node tests (domain ids, sample rows, diagnostics)
fleet_gen          a robot fleet's daily rosbag2 recordings, from the physics alone
"""
