"""The driver node: reads the card's serial stream in a thread and publishes samples."""

from collections import Counter
import json
import math
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from motor_id.card.protocol import (encode_command, FLAG_STARTUP, FrameParser, MAX_FRAME,
                                    SequenceTracker, SetPeriod, SetVoltage, StartProfile, Stop)
from motor_id.card.transport import open_transport, read_available, TransportError, write_all
from motor_id.errors import ConfigError, MotorIdError, ProtocolError
from motor_id.excitation import PROFILES
from motor_id.nodes import messages
from motor_id.nodes.common import declare_parameters, ParamSpec, RCLError, run_node

EXTERNAL = 'external'
GARBLED_BYTES = 4 * MAX_FRAME
"""Bytes in a row without one valid frame that mark the link garbled (wrong baud rate,
wrong device, electrical noise): longer than any frame, so a torn or corrupt frame or
a burst of line noise between good frames never does."""

PARAMETERS = (
    ParamSpec('device', '/dev/ttyACM0', 'card device path or pyserial URL (loop://, '
              'socket://host:port, a pty path)'),
    ParamSpec('baud', 115200, 'serial line rate [bit/s]', low=50, high=12000000),
    ParamSpec('sample_period', 0.01, 'card sample period sent at start [s]', low=1e-5,
              high=10.0),
    ParamSpec('excitation', 'paper_steps', 'profile the card runs at start; external: '
              'forward the voltage_command topic', choices=PROFILES + (EXTERNAL,)),
    ParamSpec('autostart', True, 'send the excitation when the device first opens (false: '
              'wait for ~/start)'),
    ParamSpec('amplitude', 9.0, 'profile amplitude [V]', low=0.0, high=1000.0),
    ParamSpec('duration', 40.0, 'profile length [s]; the card holds 0 V afterwards',
              low=0.001, high=1e6),
    ParamSpec('seed', 0, 'seed of random profiles (prbs, multisine)', low=0,
              high=2 ** 32 - 1),
    ParamSpec('input_kind', 'voltage', 'what the voltage column carries (bag metadata)',
              choices=('voltage', 'torque')),
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


class DriverNode(Node):
    """Card driver: serial frames in, `samples` batches and per-channel topics out.

    A reader thread does the blocking reads, parsing, sequence accounting, publishing
    and recording; the executor only runs the diagnostics timer, the voltage command
    subscription and the start/stop services. The device may be absent at start or
    vanish: the thread reopens it with exponential backoff, logs each fault kind once
    per outage, and the sequence numbers show the gap downstream.
    """

    def __init__(self):
        super().__init__('driver')
        self.settings = declare_parameters(self, PARAMETERS)
        s = self.settings
        if not s['device']:
            raise ConfigError('parameter device: got an empty string; allowed: a device '
                              'path or pyserial URL')
        self.device = s['device']
        self.parser = FrameParser()
        self.tracker = SequenceTracker()
        self.counts = Counter()          # samples, published, transport faults, reopen
        self.link = 'connecting'
        self._logged = set()             # fault kinds already logged (this outage)
        self._port = None
        self._port_lock = threading.Lock()
        self._stop = threading.Event()
        self._started_profile = False
        self._last_frame = None
        self._bytes_since_frame = 0
        self._rate = (time.monotonic(), 0, 0.0)
        self.writer = None
        if s['record_path']:
            self.writer = self._open_writer(s['record_path'])
        self.samples_pub = self.create_publisher(Float64MultiArray, messages.SAMPLES_TOPIC,
                                                 messages.SAMPLES_QOS)
        self.channel_pubs = {}
        if s['publish_channels']:
            self.channel_pubs = {name: self.create_publisher(Float64, name,
                                                             messages.CHANNEL_QOS)
                                 for name in messages.CHANNEL_TOPICS}
        self.diag_pub = self.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                              messages.DIAGNOSTICS_QOS)
        if s['excitation'] == EXTERNAL:
            self.create_subscription(Float64, messages.VOLTAGE_COMMAND_TOPIC,
                                     self._on_voltage_command, messages.CHANNEL_QOS)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_timer(1.0, self._publish_diagnostics)
        self._thread = threading.Thread(target=self._run, name='card-reader',
                                        daemon=True)
        self._thread.start()
        self.get_logger().info(
            f'driver started: device {self.device}, excitation {s["excitation"]}, '
            f'period {s["sample_period"]:g} s'
            + (f', recording to {s["record_path"]}' if self.writer else ''))

    # ------------------------------------------------------------ recording
    def _open_writer(self, path):
        from motor_id.bag import BagWriter
        s = self.settings
        meta = {
            'input_kind': s['input_kind'],
            'provenance': {'node': 'driver', 'device': s['device'],
                           'excitation': s['excitation'], 'amplitude': s['amplitude'],
                           'seed': s['seed'], 'duration': s['duration'],
                           'sample_period': s['sample_period']},
            'units': {'t': 's', 'voltage': 'V' if s['input_kind'] == 'voltage' else 'N m',
                      'speed': 'rad/s', 'current': 'A'}}
        if s['meta_file']:
            try:
                with open(s['meta_file']) as fh:
                    extra = json.load(fh)
            except (OSError, ValueError) as exc:
                raise ConfigError(f'parameter meta_file: cannot read {s["meta_file"]!r}: '
                                  f'{exc}') from None
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
                              f'{exc}') from None
        return writer

    # ------------------------------------------------------------ the reader thread
    def _fault(self, kind, text, level='warning'):
        """Log a fault the first time its kind occurs (per outage); always count it."""
        self.counts[kind] += 1
        if kind in self._logged:
            return
        self._logged.add(kind)
        text = f'{text} (further {kind} faults are counted in /diagnostics, not logged)'
        log = self.get_logger()   # rclpy wants one severity per call site
        if level == 'info':
            log.info(text)
        elif level == 'error':
            log.error(text)
        else:
            log.warning(text)

    def _open(self):
        """Try to open the device once; return the port or None."""
        try:
            port = open_transport(self.device, self.settings['baud'],
                                  self.settings['read_timeout'])
        except TransportError as exc:
            self.link = 'disconnected'
            self._fault('open_failed', f'{exc}; retrying with backoff')
            return None
        self.parser.reset()
        if self.counts['reopened'] or self.counts['lost_device']:
            self.get_logger().info(f'device {self.device} reopened')
        else:
            self.get_logger().info(f'device {self.device} open')
        self.counts['reopened'] += 1
        self._logged = {k for k in self._logged if k not in ('open_failed', 'lost_device')}
        return port

    def _configure(self):
        """Send the sample period and, the first time, the excitation."""
        s = self.settings
        commands = [SetPeriod(s['sample_period'])]
        if s['excitation'] != EXTERNAL and s['autostart'] and not self._started_profile:
            commands.append(self._profile_command())
            self._started_profile = True
        for cmd in commands:
            self.send(cmd)

    def _profile_command(self):
        s = self.settings
        return StartProfile(s['excitation'], s['amplitude'], s['seed'], s['duration'])

    def _run(self):
        """Thread body: the read loop, restarted after an unexpected error."""
        while not self._stop.is_set():
            try:
                self._read_loop()
            except Exception as exc:  # noqa: B902 - the reader must outlive any bug
                self._fault(f'internal_{type(exc).__name__}',
                            f'reader thread error {type(exc).__name__}: {exc}; restarting',
                            'error')
                self._stop.wait(1.0)

    def _read_loop(self):
        backoff = 0.05
        batch = []
        flush_at = time.monotonic()
        while not self._stop.is_set():
            port = self._port
            if port is None:
                port = self._open()
                if port is None:
                    self._stop.wait(backoff)
                    backoff = min(2 * backoff, self.settings['reopen_backoff_max'])
                    continue
                backoff = 0.05
                with self._port_lock:
                    self._port = port
                self.link = 'connected'
                self._last_frame = time.monotonic()
                self._bytes_since_frame = 0
                try:
                    self._configure()
                except MotorIdError as exc:
                    self._fault('command_failed', f'configuring the card failed: {exc}')
            try:
                data = read_available(port)
            except TransportError as exc:
                if batch:   # what was read before the loss goes out now, not after it
                    self._emit(batch)
                    batch = []
                self._lose_device(f'{exc}')
                continue
            if data:
                self._bytes_since_frame += len(data)
                self._handle(self.parser.feed(data), batch)
                self._check_garbled()
            now = time.monotonic()
            if batch and (len(batch) >= self.settings['batch_size'] or not data or
                          now - flush_at > 0.1):
                self._emit(batch)
                batch = []
                flush_at = now
            if not batch:
                flush_at = now
            if self._last_frame is not None and self.link == 'connected' and \
                    now - self._last_frame > self.settings['stall_timeout']:
                self.link = 'stalled'
        if batch:
            self._emit(batch)

    def _check_garbled(self):
        """Bytes keep coming but none of them is a frame: say so once, and what to check."""
        if self._bytes_since_frame < GARBLED_BYTES or self.link == 'garbled':
            return
        self.link = 'garbled'
        self._fault('garbled', f'no valid frame in {self._bytes_since_frame} bytes: check '
                    f'the baud rate (the driver uses {self.settings["baud"]} bit/s) and the '
                    'device')

    def _lose_device(self, text):
        self.link = 'disconnected'
        self._fault('lost_device', f'device lost: {text}; reopening with backoff')
        with self._port_lock:
            port, self._port = self._port, None
        try:
            port.close()
        except (OSError, ValueError):
            pass

    def _handle(self, items, batch):
        """Count and sort parsed items; good samples go into ``batch``."""
        for item in items:
            if isinstance(item, ProtocolError):
                self._fault(f'frame_{item.kind}', f'bad frame from the card: {item}')
                continue
            self.counts['frames_ok'] += 1
            self._last_frame = time.monotonic()
            self._bytes_since_frame = 0
            if self.link in ('stalled', 'garbled'):
                self.link = 'connected'
            ev = self.tracker.update(item.seq, restart=bool(item.flags & FLAG_STARTUP))
            if ev.kind == 'gap':
                self._fault('lost_frames', f'{ev.lost} frame(s) lost before seq {ev.seq}')
            elif ev.kind == 'reset':
                self._fault('card_reset', f'the card restarted its sequence at {ev.seq}',
                            'info')
            elif ev.kind in ('duplicate', 'late'):
                self._fault(f'{ev.kind}_frames', f'{ev.kind} frame seq {ev.seq} dropped')
                continue
            batch.append((item.seq, item.t_card, item.voltage, item.speed, item.current,
                          item.flags))
        while self.parser.replies:
            reply = self.parser.replies.popleft()
            if reply.status != 'ok':
                self._fault(f'reply_{reply.status}', f'the card answered {reply.status} to '
                            f'{reply.command}')

    def _emit(self, batch):
        rows = np.asarray(batch, dtype=float)
        if self.writer is not None:
            try:
                self.writer.write_samples(rows, self.get_clock().now().nanoseconds)
            except (MotorIdError, OSError) as exc:
                self._fault('record_failed', f'recording failed: {exc}', 'error')
        self._publish(self.samples_pub, messages.rows_to_msg(rows))
        for name, pub in self.channel_pubs.items():
            col = {'voltage': 2, 'speed': 3, 'current': 4}[name]
            for value in rows[:, col]:
                if not (name == 'current' and math.isnan(value)):
                    self._publish(pub, messages.float_msg(value))
        self.counts['samples_published'] += rows.shape[0]

    def _publish(self, pub, msg):
        try:
            pub.publish(msg)
        except RCLError:
            if self.context.ok():
                raise
            self._stop.set()   # the context shut down under us: leave quietly

    # ------------------------------------------------------------ commands
    def send(self, command):
        """Encode and write one command to the card; raises a MotorIdError if not possible."""
        data = encode_command(command)
        with self._port_lock:
            if self._port is None:
                raise TransportError(f'device {self.device} is not open')
            write_all(self._port, data)
        self.counts['commands_sent'] += 1

    def _on_voltage_command(self, msg):
        try:
            self.send(SetVoltage(msg.data))
        except (MotorIdError, ValueError) as exc:
            self._fault('command_failed', f'voltage command {msg.data!r} not sent: {exc}')

    def _on_start(self, request, response):
        if self.settings['excitation'] == EXTERNAL:
            response.success = False
            response.message = 'excitation is external: publish on voltage_command instead'
            return response
        try:
            self.send(self._profile_command())
        except MotorIdError as exc:
            response.success, response.message = False, f'not started: {exc}'
        else:
            self._started_profile = True
            response.success = True
            response.message = (f'started {self.settings["excitation"]} '
                                f'({self.samples_pub.get_subscription_count()} subscriber(s) '
                                'on samples)')
        return response

    def _on_stop(self, request, response):
        try:
            self.send(Stop())
        except MotorIdError as exc:
            response.success, response.message = False, f'not sent: {exc}'
        else:
            response.success, response.message = True, 'card holds 0 V'
        return response

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        now = time.monotonic()
        t0, n0, _ = self._rate
        n = self.counts['samples_published']
        rate = (n - n0) / (now - t0) if now > t0 else 0.0
        self._rate = (now, n, rate)
        tr = self.tracker
        bad = {k: v for k, v in self.counts.items() if k.startswith('frame_')}
        values = {'link': self.link, 'device': self.device,
                  'frames_ok': self.counts['frames_ok'], 'frames_bad': sum(bad.values()),
                  'garbage_bytes': self.parser.garbage_bytes, 'lost': tr.lost,
                  'duplicates': tr.duplicates, 'late': tr.late, 'resets': tr.resets,
                  'last_seq': tr.last, 'samples_published': n, 'rate_hz': round(rate, 2),
                  'opens': self.counts['reopened'],
                  'device_lost': self.counts['lost_device'],
                  'open_failures': self.counts['open_failed'],
                  'commands_sent': self.counts['commands_sent']}
        values.update(sorted(bad.items()))
        if self.writer is not None:
            values['record_path'] = self.settings['record_path']
        if self.link == 'disconnected':
            level, text = messages.ERROR, f'device {self.device} not available'
        elif self.link != 'connected':
            level, text = messages.WARN, f'link {self.link}'
        elif tr.lost or bad:
            level, text = messages.WARN, 'streaming, with lost or bad frames'
        else:
            level, text = messages.OK, 'streaming'
        st = messages.status('motor_id: driver', level, text, values,
                             hardware_id=self.device)
        self._publish(self.diag_pub,
                      messages.diagnostic_array(self.get_clock().now().to_msg(), [st]))

    # ------------------------------------------------------------ shutdown
    def stop(self):
        """Stop the reader thread, hold the card at 0 V, close the port and the bag."""
        self._stop.set()
        self._thread.join(5.0)
        try:
            self.send(Stop())
        except MotorIdError:
            pass
        with self._port_lock:
            port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (OSError, ValueError):
                pass
        if self.writer is not None:
            try:
                self.writer.close()
            except (MotorIdError, OSError) as exc:
                self.get_logger().error(f'closing the recording failed: {exc}')
            self.writer = None


def main(args=None):
    """Console script `driver`: spin the node until Ctrl-C / SIGTERM."""
    return run_node(DriverNode, 'driver', num_threads=1, args=args)


if __name__ == '__main__':
    sys.exit(main())
