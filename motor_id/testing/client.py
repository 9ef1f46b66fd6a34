"""A ROS client for scripts and tests: a node in its own context, spun in a thread."""

from collections.abc import Callable
import threading
import time
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from std_srvs.srv import Trigger

from motor_id.errors import MotorIdError
from motor_id.nodes.common import StopSignal
from motor_id.testing.procs import use_ros_env

NOT_YET = 'no complete excitation profile'
"""The identifier's refusal while the end of the profile has not reached it."""


class RosClient:
    """An rclpy node bound to ``domain``, spun by a background executor.

    Every call waits on its own future, never by spinning in the caller's thread, so
    the client can be used from any thread while callbacks keep running. :meth:`close`
    ends the spinning thread before it destroys anything (a spin running into a
    destroyed node raises "cannot use Destroyable because destruction was requested").

    Parameters
    ----------
    domain : int
        ROS_DOMAIN_ID (LOCALHOST discovery is selected before rclpy initialises).
    name : str
        Node name.
    """

    def __init__(self, domain: int, name: str = 'motor_id_client') -> None:
        use_ros_env(domain)
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = StopSignal()
        self._stop.attach(self.node)
        self._thread = threading.Thread(target=self._spin, name=f'{name}-spin', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self._stop.spin(self.executor)
        except ExternalShutdownException:
            pass

    def subscribe(self, msg_type: type, topic: str, qos: Any,
                  callback: Callable[[Any], None]) -> Any:
        """Subscribe ``callback`` to ``topic``."""
        return self.node.create_subscription(msg_type, topic, callback, qos)

    def collect(self, msg_type: type, topic: str, qos: Any) -> list[Any]:
        """Subscribe and return a list that fills with the received messages."""
        box: list[Any] = []
        self.subscribe(msg_type, topic, qos, box.append)
        return box

    def call_async(self, srv_type: Any, name: str, request: Any = None,
                   wait_service: float = 20.0) -> Any:
        """Start a service call; return its future.

        Raises
        ------
        MotorIdError
            The service did not appear within ``wait_service`` [s].
        """
        cli = self.node.create_client(srv_type, name)
        if not cli.wait_for_service(timeout_sec=wait_service):
            self.node.destroy_client(cli)
            raise MotorIdError(f'service {name} did not appear in {wait_service:g} s')
        return cli.call_async(request if request is not None else srv_type.Request())

    def call(self, srv_type: Any, name: str, request: Any = None, timeout: float = 60.0,
             wait_service: float = 20.0) -> Any:
        """Call a service and wait for the response.

        Raises
        ------
        MotorIdError
            The service did not appear, or did not answer within ``timeout`` [s].
        """
        future = self.call_async(srv_type, name, request, wait_service)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout):
            raise MotorIdError(f'service {name} did not answer in {timeout:g} s')
        return future.result()

    def trigger(self, name: str, timeout: float = 60.0,
                wait_service: float = 20.0) -> tuple[bool, str]:
        """Call a ``std_srvs/Trigger`` service; return ``(success, message)``."""
        res = self.call(Trigger, name, timeout=timeout, wait_service=wait_service)
        return res.success, res.message

    def identify(self, service: str = '/identifier/identify', retry_for: float = 120.0,
                 timeout: float = 120.0) -> tuple[bool, str]:
        """Call an identifier's ``~/identify`` until its answer is more than "the profile
        has not ended in my window yet" (its last rows may arrive after the caller saw the
        profile's end: a loaded machine delays them by seconds), or ``retry_for`` [s]."""
        deadline = time.monotonic() + retry_for
        while True:
            ok, text = self.trigger(service, timeout=timeout)
            if ok or NOT_YET not in text or time.monotonic() > deadline:
                return ok, text
            time.sleep(0.2)

    def close(self, timeout: float = 60.0) -> None:
        """Stop spinning, then destroy the node and shut its context down.

        Raises
        ------
        MotorIdError
            The spinning thread did not end within ``timeout`` [s] (a callback hangs);
            nothing is destroyed under it.
        """
        self._stop.set()
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise MotorIdError(f"the client's spin thread did not end in {timeout:g} s")
        self._stop.detach()
        self.executor.shutdown(timeout_sec=timeout)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
