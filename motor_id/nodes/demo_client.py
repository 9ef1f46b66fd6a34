"""The demo's client node: start the card's profile, wait for its end, call ~/identify."""

import json
import threading
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from motor_id.contracts import FLAG_PROFILE_END
from motor_id.errors import MotorIdError
from motor_id.nodes import messages


class DemoClient:
    """An rclpy node spun in a background thread; every call waits on a future.

    Parameters
    ----------
    domain : int
        ROS domain id of the demo graph.
    """

    def __init__(self, domain):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('motor_id_demo', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.samples = 0
        self.profile_end = threading.Event()
        self.reports = []
        self.node.create_subscription(Float64MultiArray, messages.SAMPLES_TOPIC,
                                      self._on_samples, messages.SAMPLES_QOS)
        self.node.create_subscription(String, '/identifier/report', self._on_report,
                                      messages.LATCHED_QOS)
        self.status = {}
        self.node.create_subscription(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                      self._on_diagnostics, messages.DIAGNOSTICS_QOS)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def _on_samples(self, msg):
        rows = messages.msg_to_rows(msg)
        self.samples += rows.shape[0]
        if np.any(rows[:, 5].astype(int) & FLAG_PROFILE_END):
            self.profile_end.set()

    def _on_diagnostics(self, msg):
        for st in msg.status:
            self.status[st.name] = {kv.key: kv.value for kv in st.values}

    def wait_identifier_receiving(self, timeout=30.0):
        """Wait until the identifier reports received samples (it is subscribed)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if int(float(self.status.get('motor_id: identifier', {})
                             .get('received', 0))) > 0:
                    return True
            except ValueError:
                pass
            time.sleep(0.1)
        return False

    def _on_report(self, msg):
        self.reports.append(json.loads(msg.data))

    def call(self, service, timeout=60.0, wait_service=20.0):
        """Call a std_srvs/Trigger service; returns (success, message)."""
        cli = self.node.create_client(Trigger, service)
        try:
            if not cli.wait_for_service(timeout_sec=wait_service):
                raise MotorIdError(f'service {service} did not appear in {wait_service:g} s')
            fut = cli.call_async(Trigger.Request())
            done = threading.Event()
            fut.add_done_callback(lambda _f: done.set())
            if not done.wait(timeout):
                raise MotorIdError(f'service {service} did not answer in {timeout:g} s')
            res = fut.result()
            return res.success, res.message
        finally:
            self.node.destroy_client(cli)

    def identify(self, retry_for=10.0):
        """Call /identifier/identify, retrying while the last rows are still arriving."""
        deadline = time.monotonic() + retry_for
        while True:
            ok, text = self.call('/identifier/identify')
            if ok or 'no complete' not in text or time.monotonic() > deadline:
                return ok, text
            time.sleep(0.3)

    def wait_report(self, count, timeout=10.0):
        """Wait until at least ``count`` reports were received; return the last."""
        deadline = time.monotonic() + timeout
        while len(self.reports) < count and time.monotonic() < deadline:
            time.sleep(0.05)
        return self.reports[-1] if self.reports else None

    def close(self):
        """Shut the node and its context down."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(5.0)
