"""The driver node: a card link in a reader thread, samples and joint states out."""

from collections.abc import Mapping
import json
import math
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from motor_id.bag import BagWriter
from motor_id.card.link import CardLink, SampleClock
from motor_id.card.protocol import Sample, Stop
from motor_id.card.session import EXTERNAL, KEEPALIVE, Session
from motor_id.card.supervisor import Limits
from motor_id.contracts import CHANNEL_COLUMNS, channel_units, INPUT_KINDS, JOINT_STATES_TOPIC
from motor_id.errors import ConfigError, MotorIdError
from motor_id.excitation import PROFILES
from motor_id.nodes import messages
from motor_id.nodes.common import declare_parameters, ParamSpec, run_node
from motor_id.nodes.rclshim import RCLError

COMMAND_QOS = qos_profile_sensor_data
"""``voltage_command``: best effort, so reliable and best-effort publishers both match."""

PARAMETERS = (
    ParamSpec('device', '/dev/ttyACM0', 'card device path or pyserial URL (loop://, '
              'socket://host:port, a pty path)'),
    ParamSpec('baud', 115200, 'serial line rate [bit/s]', low=50, high=12000000),
    ParamSpec('sample_period', 0.01, 'card sample period sent at start [s]', low=1e-5,
              high=10.0),
    ParamSpec('excitation', 'paper_steps', 'profile ~/start runs; external: forward the '
              'voltage_command topic', choices=PROFILES + (EXTERNAL,)),
    ParamSpec('autostart', False, 'start the excitation as soon as the device first opens '
              '(false: wait for ~/start)'),
    ParamSpec('amplitude', 9.0, 'profile amplitude [V]', low=0.0, high=1000.0),
    ParamSpec('duration', 40.0, 'profile length [s]; the card holds 0 V afterwards',
              low=0.001, high=1e6),
    ParamSpec('seed', 0, 'seed of random profiles (prbs, multisine)', low=0,
              high=2 ** 32 - 1),
    ParamSpec('max_voltage', 12.0, 'largest |voltage| any output carries [V]: commands '
              'are clamped, a larger profile amplitude is refused', low=0.01, high=1000.0),
    ParamSpec('max_speed', 100.0, '|speed| that stops the excitation and holds 0 V until '
              '~/start or ~/reset [rad/s]; 0: off', low=0.0, high=1e6),
    ParamSpec('max_current', 20.0, '|current| that stops the excitation and holds 0 V '
              'until ~/start or ~/reset [A]; 0: off', low=0.0, high=1e5),
    ParamSpec('command_timeout_s', 0.5, 'external excitation: hold 0 V after this long '
              'without a voltage_command [s]; 0: off', low=0.0, high=3600.0),
    ParamSpec('keepalive_period', KEEPALIVE, 'while a profile or a non-zero command drives '
              'the motor, ping the card when no command went out for this long [s]: the '
              "card's watchdog (0.5 s on the firmware sketch and card-sim) stops the motor "
              'when the pings stop; keep it well below the watchdog; 0: no pings',
              low=0.0, high=10.0),
    ParamSpec('input_kind', 'voltage', 'what the voltage column carries (bag metadata; '
              'joint_states effort is the torque for a torque card)',
              choices=INPUT_KINDS),
    ParamSpec('joint_name', 'motor', 'name of the joint in joint_states'),
    ParamSpec('publish_joint_states', True, 'publish sensor_msgs/JointState on '
              'joint_states, one per sample: stamp = card time + a fixed offset to ROS '
              'time (taken at the first sample), velocity = speed [rad/s], effort = '
              'current [A] (torque [N m] on a torque card), position = speed integrated '
              'over card time [rad] (0 at the first sample)'),
    ParamSpec('record_path', '', 'MCAP file to record to (empty: no recording)'),
    ParamSpec('meta_file', '', 'JSON object merged into the recording metadata (e.g. '
              '{"truth": ...} of a simulated card); empty: none'),
    ParamSpec('publish_channels', True, 'also publish voltage, speed, current as Float64'),
    ParamSpec('batch_size', 10, 'samples per samples message (sent earlier when the '
              'stream pauses)', low=1, high=100000),
    ParamSpec('read_timeout', 0.05, 'serial read timeout [s]', low=0.001, high=5.0),
    ParamSpec('reopen_backoff_max', 5.0, 'longest wait between reopen attempts [s]',
              low=0.05, high=600.0),
    ParamSpec('stall_timeout', 1.0, 'no frame for this long marks the link stalled [s]',
              low=0.01, high=3600.0),
)


def _check_settings(s: Mapping[str, Any]) -> None:
    """Cross-parameter checks (one line naming the parameter)."""
    if not s['device']:
        raise ConfigError('parameter device: got an empty string; allowed: a device '
                          'path or pyserial URL')
    if not s['joint_name']:
        raise ConfigError('parameter joint_name: got an empty string; allowed: a name')
    if s['excitation'] != EXTERNAL and s['amplitude'] > s['max_voltage']:
        raise ConfigError(f'parameter amplitude: {s["amplitude"]:g} V exceeds max_voltage '
                          f'{s["max_voltage"]:g} V, so the {s["excitation"]} profile would '
                          'be refused; lower amplitude or raise max_voltage')


class DriverNode(Node):
    """Card driver: a :class:`CardLink` read in a thread, samples and joint states out.

    The reader thread polls the link (open with back-off, read, parse, count, batch)
    and publishes the batches. A :class:`~motor_id.card.session.Session` runs the
    excitation and checks every sample against the limits, holding 0 V when one trips
    (latched until ``~/start`` or ``~/reset``). The executor runs the diagnostics
    timer, the ``voltage_command`` subscription and the ``~/start``, ``~/stop``,
    ``~/reset`` services. Nothing but parameters, messages, services and logging here.
    """

    def __init__(self) -> None:
        super().__init__('driver')
        self.settings = s = declare_parameters(self, PARAMETERS)
        _check_settings(s)
        self.device = s['device']
        self._stop_event = threading.Event()
        self._emit_lock = threading.Lock()
        self._closed = False
        self._published = 0
        self._rate = (time.monotonic(), 0, 0.0)
        self.link = CardLink(self.device, s['baud'], s['read_timeout'],
                             s['reopen_backoff_max'], s['stall_timeout'], s['batch_size'],
                             sample_period=s['sample_period'], log=self._log,
                             on_open=lambda: self.session.on_open(),
                             on_sample=lambda x: self.session.on_sample(x),
                             on_reply=lambda r: self.session.on_reply(r),
                             stop=self._stop_event)
        self.session = Session(
            self.link, Limits(s['max_voltage'], s['max_speed'], s['max_current'],
                              s['command_timeout_s']),
            s['excitation'], s['amplitude'], s['seed'], s['duration'], s['sample_period'],
            s['autostart'], log=self._log, keepalive=s['keepalive_period'])
        self.clock = SampleClock()
        self.writer = self._open_writer(s['record_path']) if s['record_path'] else None
        self.samples_pub = self.create_publisher(Float64MultiArray, messages.SAMPLES_TOPIC,
                                                 messages.SAMPLES_QOS)
        self.channel_pubs = {}
        if s['publish_channels']:
            self.channel_pubs = {name: self.create_publisher(Float64, name,
                                                             messages.CHANNEL_QOS)
                                 for name in messages.CHANNEL_TOPICS}
        self.joint_pub = None
        if s['publish_joint_states']:
            self.joint_pub = self.create_publisher(JointState, JOINT_STATES_TOPIC,
                                                   messages.CHANNEL_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                              messages.DIAGNOSTICS_QOS)
        if s['excitation'] == EXTERNAL:
            self.create_subscription(Float64, messages.VOLTAGE_COMMAND_TOPIC,
                                     self._on_voltage_command, COMMAND_QOS)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_timer(1.0, self._publish_diagnostics)
        self._thread = threading.Thread(target=self._run, name='card-reader', daemon=True)
        self._thread.start()
        self.get_logger().info(
            f'driver started: device {self.device}, excitation {s["excitation"]}, '
            f'period {s["sample_period"]:g} s, max_voltage {s["max_voltage"]:g} V'
            + (f', recording to {s["record_path"]}' if self.writer else ''))

    def _log(self, level: str, text: str) -> None:
        log = self.get_logger()   # rclpy wants one severity per call site
        if level == 'info':
            log.info(text)
        elif level == 'error':
            log.error(text)
        else:
            log.warning(text)

    # ------------------------------------------------------------ recording
    def _open_writer(self, path: str) -> BagWriter:
        from motor_id.bag import BagWriter
        s = self.settings
        meta = {
            'input_kind': s['input_kind'],
            'provenance': {'node': 'driver', 'device': s['device'],
                           'excitation': s['excitation'], 'amplitude': s['amplitude'],
                           'seed': s['seed'], 'duration': s['duration'],
                           'sample_period': s['sample_period']},
            'units': channel_units(s['input_kind'])}
        if s['meta_file']:
            try:
                with open(s['meta_file']) as fh:
                    extra = json.load(fh)
            except (OSError, ValueError) as exc:
                raise ConfigError(f'parameter meta_file: cannot read {s["meta_file"]!r}: '
                                  f'{exc}') from exc
            if not isinstance(extra, dict):
                raise ConfigError(f'parameter meta_file: {s["meta_file"]!r} must hold a '
                                  'JSON object')
            for key, value in extra.items():
                if isinstance(value, dict) and isinstance(meta.get(key), dict):
                    meta[key] = {**meta[key], **value}
                else:
                    meta[key] = value
        try:
            writer = BagWriter(path)
            writer.write_meta(meta, log_time_ns=self.get_clock().now().nanoseconds)
        except (MotorIdError, OSError) as exc:
            raise ConfigError(f'parameter record_path: cannot record to {path!r}: '
                              f'{exc}') from exc
        return writer

    # ------------------------------------------------------------ the reader thread
    def _run(self) -> None:
        """Thread body: poll the link, publish batches; restarted after a bug."""
        while not self._stop_event.is_set():
            try:
                for batch in self.link.poll():
                    self._emit(batch)
                    self.session.keep_alive()   # also between batches: a busy reader
                self.session.check_watchdog()
                self.session.keep_alive()
            except Exception as exc:  # noqa: BLE001 - the reader must outlive any bug
                self.link.fault(f'internal_{type(exc).__name__}',
                                f'reader thread error {type(exc).__name__}: {exc}; '
                                'restarting', 'error')
                self._stop_event.wait(1.0)
        for batch in self.link.flush():
            self._emit(batch)

    def _emit(self, batch: list[Sample]) -> None:
        with self._emit_lock:
            if not self._closed:   # after stop() the node may be destroyed: touch nothing
                self._emit_unlocked(batch)

    def _emit_unlocked(self, batch: list[Sample]) -> None:
        rows = np.array([(x.seq, x.t_card, x.voltage, x.speed, x.current, x.flags)
                         for x in batch], dtype=float)
        now_ns = self.get_clock().now().nanoseconds
        if self.writer is not None:
            try:
                self.writer.write_samples(rows, now_ns)
            except (MotorIdError, OSError) as exc:
                self.link.fault('record_failed', f'recording failed: {exc}', 'error')
        self._publish(self.samples_pub, messages.rows_to_msg(rows))
        for name, pub in self.channel_pubs.items():
            for value in rows[:, CHANNEL_COLUMNS[name]]:
                if not (name == 'current' and math.isnan(value)):
                    self._publish(pub, messages.float_msg(value))
        for x in batch:
            stamp = self.clock.update(x, now_ns)
            if self.joint_pub is not None:
                self._publish(self.joint_pub, self._joint_state(x, stamp))
        self._published += rows.shape[0]

    def _joint_state(self, sample: Sample, stamp_ns: int) -> JointState:
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), 10 ** 9)
        msg.name = [self.settings['joint_name']]
        msg.position = [self.clock.position]
        msg.velocity = [sample.speed]
        torque = self.settings['input_kind'] == 'torque'
        msg.effort = [sample.voltage if torque else sample.current]
        return msg

    def _publish(self, pub: Any, msg: Any) -> None:
        try:
            pub.publish(msg)
        except RCLError:
            if self.context.ok():
                raise
            self._stop_event.set()   # the context shut down under us: leave quietly

    # ------------------------------------------------------------ commands
    def _on_voltage_command(self, msg: Float64) -> None:
        self.session.command(msg.data)

    def _on_start(self, request: Trigger.Request,
                  response: Trigger.Response) -> Trigger.Response:
        try:
            text = self.session.start()
        except MotorIdError as exc:
            response.success, response.message = False, f'not started: {exc}'
        else:
            response.success = True
            response.message = (f'{text} ({self.samples_pub.get_subscription_count()} '
                                'subscriber(s) on samples)')
        return response

    def _on_stop(self, request: Trigger.Request,
                 response: Trigger.Response) -> Trigger.Response:
        try:
            self.session.stop()
        except MotorIdError as exc:
            response.success, response.message = False, f'not sent: {exc}'
        else:
            response.success, response.message = True, 'card holds 0 V'
        return response

    def _on_reset(self, request: Trigger.Request,
                  response: Trigger.Response) -> Trigger.Response:
        try:
            text = self.session.reset()
        except MotorIdError as exc:
            response.success, response.message = False, f'limits re-armed, 0 V not sent: {exc}'
        else:
            response.success, response.message = True, text
        return response

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        t0, n0, _ = self._rate
        n = self._published
        rate = (n - n0) / (now - t0) if now > t0 else 0.0
        self._rate = (now, n, rate)
        values = self.link.values()
        values.update(samples_published=n, rate_hz=round(rate, 2))
        values.update(self.session.values())
        if self.writer is not None:
            values['record_path'] = self.settings['record_path']
        level, text = self._status(values)
        st = messages.status('motor_id: driver', level, text, values,
                             hardware_id=self.device)
        self._publish(self.diag_pub,
                      messages.diagnostic_array(self.get_clock().now().to_msg(), [st]))

    def _status(self, values: Mapping[str, Any]) -> tuple[int, str]:
        supervisor = self.session.supervisor
        trip = supervisor.trip
        if trip is not None:
            return messages.ERROR, f'excitation stopped by the {trip.describe()}'
        if values['link'] == 'disconnected':
            return messages.ERROR, f'device {self.device} not available'
        if values['link'] != 'connected':
            return messages.WARN, f'link {values["link"]}'
        if supervisor.watchdog_holding:
            return messages.WARN, 'no voltage_command: watchdog holds 0 V'
        if 'line_overload' in values:
            return messages.WARN, 'streaming, but the line is too slow for the sample rate'
        if values['lost'] or values['frames_bad']:
            return messages.WARN, 'streaming, with lost or bad frames'
        return messages.OK, 'streaming'

    # ------------------------------------------------------------ shutdown
    def last_resort(self) -> None:
        """0 V to the card now, from any thread: the process is ended next (its stop took
        too long, see :class:`motor_id.nodes.common.SignalWatcher`)."""
        self.session.close()

    def stop(self) -> None:
        """Command 0 V first, then stop the reader thread, close the port and the bag.

        After it the node publishes nothing more (it may be destroyed), whether or not
        the reader thread ended within its 5 s.
        """
        self.session.close()        # 0 V now, and nothing but zeros from here on
        self._stop_event.set()
        self._thread.join(5.0)
        with self._emit_lock:
            self._closed = True
        try:
            self.link.send(Stop())   # once more: the reader may have reopened the port
        except MotorIdError:
            pass
        self.link.close()
        if self.writer is not None:
            try:
                self.writer.close()
            except (MotorIdError, OSError) as exc:
                self.get_logger().error(f'closing the recording failed: {exc}')
            self.writer = None


def main(args: list[str] | None = None) -> int:
    """Console script `driver`: spin the node until Ctrl-C / SIGTERM."""
    return run_node(DriverNode, 'driver', num_threads=1, args=args)


if __name__ == '__main__':
    sys.exit(main())
