"""The demo's client: start the card's profile, wait for its end, call ~/identify."""

import json
import threading
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from std_msgs.msg import Float64MultiArray, String

from motor_id.contracts import FLAG_PROFILE_END, FLAGS
from motor_id.nodes import messages
from motor_id.testing.client import RosClient
from motor_id.testing.procs import wait_until


class DemoClient(RosClient):
    """A :class:`RosClient` that counts samples, sees the profile end and keeps reports.

    Parameters
    ----------
    domain : int
        ROS domain id of the demo graph.
    """

    def __init__(self, domain: int) -> None:
        super().__init__(domain, 'motor_id_demo')
        self.samples = 0
        self.profile_end = threading.Event()
        self.reports: list[dict[str, Any]] = []
        self.status: dict[str, dict[str, str]] = {}
        self.subscribe(Float64MultiArray, messages.SAMPLES_TOPIC, messages.SAMPLES_QOS,
                       self._on_samples)
        self.subscribe(String, '/identifier/' + messages.REPORT_TOPIC, messages.LATCHED_QOS,
                       lambda msg: self.reports.append(json.loads(msg.data)))
        self.subscribe(DiagnosticArray, messages.DIAGNOSTICS_TOPIC, messages.DIAGNOSTICS_QOS,
                       self._on_diagnostics)

    def _on_samples(self, msg: Float64MultiArray) -> None:
        rows = messages.msg_to_rows(msg)
        self.samples += rows.shape[0]
        if np.any(rows[:, FLAGS].astype(int) & FLAG_PROFILE_END):
            self.profile_end.set()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            self.status[st.name] = {kv.key: kv.value for kv in st.values}

    def _received(self) -> int:
        try:
            return int(float(self.status.get('motor_id: identifier', {}).get('received', 0)))
        except ValueError:
            return 0

    def wait_identifier_receiving(self, timeout: float = 30.0) -> bool:
        """Wait until the identifier reports received samples (it is subscribed)."""
        return wait_until(lambda: self._received() > 0, timeout, 0.1)


    def wait_report(self, count: int, timeout: float = 10.0) -> dict[str, Any] | None:
        """Wait until at least ``count`` reports were received; return the last."""
        wait_until(lambda: len(self.reports) >= count, timeout)
        return self.reports[-1] if self.reports else None
