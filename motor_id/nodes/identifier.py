"""The identifier node: buffers `samples`, fits on request, publishes latched estimates."""

from collections.abc import Callable
import datetime as dt
import sys
import threading
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from motor_id import pipeline
from motor_id.contracts import INPUT_KINDS, units_of
from motor_id.data.align import ALIGN_RULES
from motor_id.data.buffer import SampleBuffer
from motor_id.errors import ConfigError, DataError, MotorIdError
from motor_id.fleet.history import DriftRow
from motor_id.fleet.live import drift_message, EstimateHistory
from motor_id.fleet.rows import ParameterValue
from motor_id.identify import FitSettings, Identifier, METHODS, parse_bounds, parse_fixed
from motor_id.identify.result import IdentificationResult
from motor_id.model import PARAM_NAMES
from motor_id.nodes import messages
from motor_id.nodes.common import (
    declare_parameters,
    drain,
    InFlight,
    ParamSpec,
    run_node,
    StopSignal,
    TopicWatch,
)
from motor_id.nodes.topic_input import TopicInput

FITTED = tuple(n for n in PARAM_NAMES if n != 'R_m')


def _items(text: str) -> list[str]:
    """The comma-separated items of a string parameter."""
    return [x for x in text.split(',') if x.strip()]


def fixed_values(text: str, name: str = 'fix') -> dict[str, float]:
    """``fix`` parameter -> {NAME: value}; raises ConfigError starting with ``name``."""
    fixed = parse_fixed(_items(text), name)
    if 'R_m' in fixed:
        raise ConfigError(f'{name}: R_m is set by the parameter R_m')
    return fixed


def bound_values(text: str, name: str = 'bounds') -> dict[str, tuple[float, float]]:
    """``bounds`` parameter -> {NAME: (low, high)}; raises ConfigError starting with ``name``."""
    bounds = parse_bounds(_items(text), name)
    unknown = sorted(set(bounds) - set(FITTED))
    if unknown:
        raise ConfigError(f'{name}: {", ".join(unknown)} is not fitted; use '
                          f'{", ".join(FITTED)}')
    return bounds


def fit_settings(p: dict[str, Any]) -> FitSettings:
    """The :class:`~motor_id.identify.FitSettings` of the node's parameter values."""
    return FitSettings(method=p['method'], R_m=p['R_m'],
                       tie=None if p['tie_kt_kb'] == 'auto' else bool(p['tie_kt_kb']),
                       population=p['population'], generations=p['generations'],
                       random_state=p['seed'], fixed=fixed_values(p['fix']) or None,
                       bounds=bound_values(p['bounds']) or None)


def warm_up(settings: FitSettings, input_kind: str, logger: Any,
            progress: Callable[[int, int, float], bool]) -> None:
    """Load the compiled kernels and run a tiny fit (``settings`` at 4 x 2 generations)
    on synthetic data before serving, so that the first ~/identify does not stall
    reception (logged; ``progress`` returning True, at a stop, cancels its GA)."""
    from motor_id import simulate
    from motor_id.model import Plant
    started = time.perf_counter()
    kernels = simulate.warm_up()   # every kernel: regular, irregular, with effects
    t = np.arange(200) * 0.01
    u = np.where((t // 0.25) % 2 > 0, 6.0, -3.0)
    rec = simulate.simulate_recording(Plant(input_kind=input_kind), t, u, 0.01, 0.01,
                                      random_state=0)
    try:
        tiny = settings.replace(population=4, generations=2, random_state=0, fixed=None,
                                bounds=None)
        Identifier(tiny).fit(rec, progress=progress)
    except MotorIdError as exc:
        logger.warning(f'warm-up fit: {exc}')
    logger.info(f'warmed up in {time.perf_counter() - started:.2f} s (kernels '
                f'{kernels.seconds:.2f} s, {kernels.compiled} compiled; a tiny fit)')


PARAMETERS = (
    ParamSpec('method', 'zoh', 'identification method: zoh (exact, recommended), euler, '
              'paper (as published)', choices=METHODS),
    ParamSpec('R_m', 2.3, 'known armature resistance [Ohm]', low=1e-6, high=1e6),
    ParamSpec('tie_kt_kb', 'auto', 'impose K_T = K_b (auto: when current is measured)',
              choices=('auto', True, False), dynamic=True),
    ParamSpec('input_kind', 'voltage', 'plant input on the voltage column',
              choices=INPUT_KINDS),
    ParamSpec('select', 'window', 'what to fit: window (the last window_s seconds) or '
              'profile (the latest complete excitation profile run in the window)',
              choices=('window', 'profile')),
    ParamSpec('window_s', 60.0, 'card time fitted, the most recent [s]', low=0.05,
              high=86400.0),
    ParamSpec('max_samples', 200000, 'rows kept in the buffer', low=100, high=10000000),
    ParamSpec('min_samples', 200, 'fewest rows a fit accepts', low=20, high=10000000),
    ParamSpec('allow_gaps', False, 'fit the latest gap-free segment instead of refusing a '
              'window with gaps'),
    ParamSpec('fix', '', 'parameters known in advance, e.g. "J=0.052": individual values '
              'from speed-only data need one (empty: none)',
              syntax='comma-separated NAME=VALUE, NAME in ' + ', '.join(FITTED)
              + ', VALUE > 0', validator=fixed_values),
    ParamSpec('bounds', '', 'search ranges replacing the defaults, e.g. "J=1e-4:1, '
              'B=1e-6:0.1" (empty: the defaults)',
              syntax='comma-separated NAME=LOW:HIGH, NAME in ' + ', '.join(FITTED)
              + ', 0 < LOW < HIGH', validator=bound_values),
    ParamSpec('population', 20, 'GA population', low=4, high=10000),
    ParamSpec('generations', 160, 'GA generations', low=1, high=1000000),
    ParamSpec('seed', 0, 'GA random seed', low=0, high=2 ** 31 - 1),
    ParamSpec('period_s', 0.0, 're-identify every this many seconds (0: only on request)',
              low=0.0, high=86400.0),
    ParamSpec('hardware_id', '', 'hardware_id of the diagnostics and the estimate, e.g. '
              "the driver's device (empty: the node's namespace)"),
    ParamSpec('warm_up', True, 'run a tiny fit at start-up, before serving, so that the '
              'first ~/identify does not load the compiled kernels'),
    ParamSpec('input', 'samples', "where samples come from: samples (the driver's batch "
              "topic) or topics (the robot's joint_states and input_topic)",
              choices=('samples', 'topics')),
    ParamSpec('joint_name', '', 'input topics: the JointState joint (empty: the only one)'),
    ParamSpec('input_topic', 'voltage_command', 'input topics: the plant input command '
              '(std_msgs/Float64, V), zero-order held onto the JointState samples'),
    ParamSpec('speed_field', 'velocity', 'input topics: JointState field with the speed '
              '[rad/s]', choices=messages.JOINT_FIELDS),
    ParamSpec('current_field', 'effort', 'input topics: JointState field with the current '
              "or torque ('' for none)", choices=messages.JOINT_FIELDS + ('',)),
    ParamSpec('effort_is', 'current', 'input topics: what current_field holds: current '
              '[A], or torque [N m], which is then the plant input (no input_topic)',
              choices=('current', 'torque')),
    ParamSpec('align', 'hold', 'input topics: a sample takes the command in force at its '
              'time (hold) or the last one before the next sample (next)',
              choices=ALIGN_RULES),
    ParamSpec('history_file', '', 'append every estimate to this JSON-lines file and test '
              'the history for drift with the fleet rule after each fit; a drift turns '
              '/diagnostics to WARN (empty: off)'),
)

OUTPUT_PREFIXES = ('estimate.', 'controller.')
"""Parameters the node sets after each fit (read-only for users, by convention)."""


class IdentifierNode(Node):
    """Subscribes `samples`, serves `~/identify`, publishes `~/estimate` and `~/report`.

    Reception and fitting never share a thread. This node (samples, diagnostics,
    parameters, publishers) spins on a SingleThreadedExecutor, which keeps up with one
    message per sample at 1 kHz where rclpy's MultiThreadedExecutor does not. The
    ``~/identify`` service and the periodic timer live on a hidden helper node
    (``_<name>_fit``, service name resolved through this node, so remaps apply) spun
    by its own MultiThreadedExecutor in a second thread; a fit works on a snapshot
    copied under the buffer's lock. Only one fit runs at a time: a second request
    while one runs is answered at once with ``success=False``.

    The constructor only declares parameters and creates publishers and timers; a
    one-shot timer, once the node spins, runs the warm-up (``warm_up``), subscribes the
    inputs and starts the fit thread, which creates ``~/identify`` and logs "identifier
    ready" (the order of the constructor before: nothing is received while warming up).

    Input: ``input: samples`` subscribes the driver's ``samples`` batches; ``input:
    topics`` builds the same rows from the robot's ``joint_states`` and ``input_topic``
    (:class:`motor_id.nodes.topic_input.TopicInput`). Either way a topic of the wrong
    type is reported with the type found (:class:`motor_id.nodes.common.TopicWatch`).

    Outputs after each fit: ``~/estimate`` (values with ``_std`` and ``_unit`` keys,
    ``hardware_id`` set), ``~/report`` (the fit JSON with ``"controller"``, ``"units"``,
    ``"hardware_id"``), both latched, and the parameters ``estimate.<P>``,
    ``estimate.<P>_std`` and ``controller.*`` (NaN: unknown), which a late joiner can
    read at any time; they are outputs, and a user's set is refused.
    All topic and service names are relative, so a namespace keeps motors apart;
    only ``/diagnostics`` is global.
    """

    def __init__(self) -> None:
        super().__init__('identifier')
        self.settings = declare_parameters(self, PARAMETERS)
        if self.settings['min_samples'] > self.settings['max_samples']:
            raise ConfigError(f'parameter min_samples: {self.settings["min_samples"]} is '
                              f'more than max_samples ({self.settings["max_samples"]})')
        self.buffer = SampleBuffer(self.settings['max_samples'], self.settings['window_s'])
        self._fit_lock = threading.Lock()
        self._stopping = threading.Event()
        self._bad_messages = 0
        self._fits = {'ok': 0, 'failed': 0}
        self._last = 'no fit yet'
        self.in_flight = InFlight()
        self.hardware_id = (self.settings['hardware_id'] or self.get_namespace().strip('/')
                            or self.get_name())
        self._setting_outputs = threading.local()
        self._outputs: set[str] = set()
        self.input_kind = self.settings['input_kind']
        if self.settings['input'] == 'topics' and self.settings['effort_is'] == 'torque':
            self.input_kind = 'torque'
        self.topic_input: TopicInput | None = None   # the inputs: subscribed at the start
        self.estimate_pub = self.create_publisher(DiagnosticArray,
                                                  '~/' + messages.ESTIMATE_TOPIC,
                                                  messages.LATCHED_QOS)
        self.report_pub = self.create_publisher(String, '~/' + messages.REPORT_TOPIC,
                                                messages.LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, messages.DIAGNOSTICS_TOPIC,
                                              messages.DIAGNOSTICS_QOS)
        self._history: EstimateHistory | None = None
        self._drift: list[DriftRow] = []
        if self.settings['history_file']:
            self._history = EstimateHistory(self.settings['history_file'],
                                            robot=self.hardware_id, motor=self.get_name())
        self.create_timer(1.0, self._publish_diagnostics)
        self.add_on_set_parameters_callback(self._on_set)
        self.fit_node = Node(f'_{self.get_name()}_fit', namespace=self.get_namespace(),
                             context=self.context, use_global_arguments=False,
                             start_parameter_services=False)
        self._fit_executor = MultiThreadedExecutor(num_threads=2, context=self.context)
        self._fit_executor.add_node(self.fit_node)
        self._fit_done = StopSignal()
        self._fit_done.attach(self.fit_node)
        self._serving = threading.Lock()   # serving starts, or the node stops: not both
        self._fit_thread: threading.Thread | None = None
        self._start_timer = self.create_timer(0.0, self._on_start)   # one shot, once spun

    def _on_start(self) -> None:
        """Once the node spins (a one-shot timer, not the constructor): the warm-up, then
        the inputs' subscriptions (nothing queues while the kernels load, as before), then
        the fit thread, which serves ``~/identify`` (and the periodic fits)."""
        self._start_timer.cancel()
        if self._fit_thread is not None or self._stopping.is_set():
            return
        if self.settings['warm_up']:
            warm_up(fit_settings(self.settings), self.input_kind, self.get_logger(),
                    self._progress)
        if self.settings['input'] == 'topics':
            self.topic_input = TopicInput(self, self.buffer, self.settings)
        else:
            self.create_subscription(Float64MultiArray, messages.SAMPLES_TOPIC,
                                     self._on_samples, messages.SAMPLES_QOS)
            self.samples_watch = TopicWatch(self, messages.SAMPLES_TOPIC,
                                            messages.TYPE_NAMES[Float64MultiArray])
        self._fit_thread = threading.Thread(target=self._serve, name='fit-executor',
                                            daemon=True)
        self._fit_thread.start()

    def _serve(self) -> None:
        """The fit thread: the service and the timer, then its executor."""
        guard = self.in_flight.wrap
        with self._serving:
            if self._stopping.is_set():
                return
            fit_group = ReentrantCallbackGroup()
            self.fit_node.create_service(Trigger, self.resolve_service_name('~/identify'),
                                         guard(self._on_identify), callback_group=fit_group)
            if self.settings['period_s'] > 0:
                self.fit_node.create_timer(self.settings['period_s'], guard(self._on_period),
                                           callback_group=fit_group)
            self.get_logger().info(
                f'identifier ready: method {self.settings["method"]}, window '
                f'{self.settings["window_s"]:g} s, R_m {self.settings["R_m"]:g} Ohm, input '
                f'{self.settings["input"]}')
        self._fit_done.spin(self._fit_executor)

    # ------------------------------------------------------------- callbacks
    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        internal = getattr(self._setting_outputs, 'active', False)
        for p in params:
            if p.name.startswith(OUTPUT_PREFIXES) and not internal:
                return SetParametersResult(successful=False, reason=(
                    f'{p.name} is an output of the identifier (read-only)'))
        for p in params:
            if p.name == 'window_s':
                self.buffer.window_s = float(p.value)
        return SetParametersResult(successful=True)

    def _on_samples(self, msg: Float64MultiArray) -> None:
        try:
            self.buffer.extend(messages.msg_to_rows(msg))
        except DataError as exc:
            self._bad_messages += 1
            if self._bad_messages == 1:
                self.get_logger().warning(f'ignoring malformed samples message(s): {exc}')

    def _on_identify(self, request: Trigger.Request,
                     response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.fit_window()
        return response

    def _on_period(self) -> None:
        ok, text = self.fit_window()
        if not ok and 'already running' not in text:
            self.get_logger().warning(f'periodic identification: {text}')

    def _publish_diagnostics(self) -> None:
        snap_rows = len(self.buffer)
        values: dict[str, messages.DiagnosticValue] = {
            'rows': snap_rows, 'received': self.buffer.received,
            'duplicates': self.buffer.duplicates, 'gaps': self.buffer.gaps,
            'malformed_messages': self._bad_messages, 'fits_ok': self._fits['ok'],
            'fits_failed': self._fits['failed'], 'fit_running': self._fit_lock.locked()}
        if self.topic_input is not None:
            values.update(self.topic_input.counts())
        level = messages.OK if snap_rows else messages.WARN
        text = self._last
        drifting = [d for d in self._drift if d.detected]
        if drifting:
            level, text = messages.WARN, drift_message(drifting) + '; ' + text
            for d in drifting:
                values[f'drift.{d.parameter}.change'] = f'{d.change or 0.0:.4f}'
                values[f'drift.{d.parameter}.since'] = d.since
        st = messages.status('motor_id: identifier', level, text, values,
                             self.hardware_id)
        self._publish(self.diag_pub,
                      messages.diagnostic_array(self.get_clock().now().to_msg(), [st]))

    def _publish(self, pub: Publisher, msg: DiagnosticArray | String) -> None:
        if self.context.ok():
            pub.publish(msg)

    # ------------------------------------------------------------------ work
    def fit_window(self) -> tuple[bool, str]:
        """Fit the buffered window; return ``(success, message)``. Never raises."""
        if not self._fit_lock.acquire(blocking=False):
            return False, 'a fit is already running; try again when it finishes'
        try:
            return self._fit_window()
        finally:
            self._fit_lock.release()

    def _fit_window(self) -> tuple[bool, str]:
        p = {s.name: self.get_parameter(s.name).value for s in PARAMETERS}
        started = time.perf_counter()
        try:
            snap = self.buffer.snapshot()
            if p['select'] == 'profile' and len(snap):
                snap = snap.profile_segment()
            rec = snap.recording(p['min_samples'], p['allow_gaps'], self.input_kind,
                                 {'source': 'identifier node'})
            est = Identifier(fit_settings(p))
            self.get_logger().info(
                f'fitting {len(rec)} samples ({rec.time[-1] - rec.time[0]:.2f} s of card '
                f'time, seq {rec.meta["seq_first"]}..{rec.meta["seq_last"]})')
            source = ('samples topic' if self.topic_input is None else
                      'joint_states and input topics')
            fit = pipeline.fit_report(
                rec, est, progress=self._progress,
                data={'source': source, 'seq_first': rec.meta['seq_first'],
                      'seq_last': rec.meta['seq_last'], 't_first': float(rec.time[0]),
                      't_last': float(rec.time[-1]), 'gaps_skipped': len(snap.gaps)},
                extra={'hardware_id': self.hardware_id,
                       'units': units_of(rec.input_kind)})
        except MotorIdError as exc:
            return self._failed(str(exc))
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
            self.get_logger().error(f'identification failed: {type(exc).__name__}: {exc}')
            return self._failed(f'identification failed: {type(exc).__name__}: {exc}')
        if self._stopping.is_set():
            return self._failed('cancelled: the node is shutting down')
        res = fit.result
        report = fit.to_dict()
        if fit.controller_error:
            self.get_logger().warning(f'no controller design: {fit.controller_error}')
        summary = res.summary()
        stamp = self.get_clock().now().to_msg()
        self._set_outputs(fit)
        self._publish(self.estimate_pub, messages.estimate_to_msg(
            stamp, report, summary, hardware_id=self.hardware_id))
        self._publish(self.report_pub, messages.report_msg(report))
        self._fits['ok'] += 1
        head = (f'identified from {len(rec)} samples in '
                f'{time.perf_counter() - started:.2f} s')
        self._last = head
        self._track_drift(res)
        self.get_logger().info(head + '\n' + summary)
        return True, head + '\n' + summary

    def _set_outputs(self, fit: pipeline.FitReport) -> None:
        """Set ``estimate.*`` and ``controller.*`` parameters (NaN: unknown)."""
        units = fit.extra['units']
        flat = fit.to_ros_parameters('x', unknown='nan')['x']['ros__parameters']
        values: dict[str, tuple[float, str]] = {}
        for name, value in flat.items():
            if name.startswith('estimate.'):
                sym = name[len('estimate.'):].removesuffix('_std')
                values[name] = (value, f'{sym} estimate [{units.get(sym, "")}]')
        for name in {n for n in self._outputs if n.startswith('controller.')} | \
                {n for n in flat if n.startswith('controller.')}:
            values[name] = (float(flat.get(name, float('nan'))),
                            'controller design from the latest estimate (NaN: unknown)')
        self._setting_outputs.active = True
        try:
            for name, (value, text) in values.items():
                if name not in self._outputs:
                    self._outputs.add(name)
                    self.declare_parameter(name, value, ParameterDescriptor(
                        description=text + ' - set by the identifier, read-only for users'))
                else:
                    self.set_parameters([Parameter(name, Parameter.Type.DOUBLE, value)])
        finally:
            self._setting_outputs.active = False

    def _track_drift(self, result: IdentificationResult) -> None:
        """Append the estimate to ``history_file`` and test the history for drift."""
        if self._history is None:
            return
        now = dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds')
        params = {name: ParameterValue(value=e.value, std=e.std, determined=e.determined)
                  for name, e in result.parameters.items()}
        try:
            self._history.append(params, now.replace('+00:00', 'Z'), result.adequate)
            rows = self._history.check()
        except MotorIdError as exc:
            self.get_logger().warning(f'drift check: {exc}')
            return
        was = {d.parameter for d in self._drift if d.detected}
        self._drift = rows
        new = [d for d in rows if d.detected and d.parameter not in was]
        if new:
            self.get_logger().warning(drift_message(new))

    def _failed(self, reason: str) -> tuple[bool, str]:
        self._fits['failed'] += 1
        self._last = f'last fit refused: {reason}'
        self.get_logger().warning(f'identify: {reason}')
        return False, reason

    def _progress(self, generation: int, generations: int, best_cost: float) -> bool:
        return self._stopping.is_set() or not self.context.ok()

    def stop(self) -> None:
        """Stop a running fit at its next generation, then the fit node's executor."""
        with self._serving:
            self._stopping.set()
        if not self.in_flight.wait_idle(10.0):
            self.get_logger().warning('a fit is still running at shutdown')
        self._fit_done.set()
        if self._fit_thread is not None:
            self._fit_thread.join(5.0)
        drain(self._fit_executor, self)
        self._fit_done.detach()
        self._fit_executor.shutdown(timeout_sec=1.0)
        self.fit_node.destroy_node()


def main(args: list[str] | None = None) -> int:
    """Console script `identifier`: spin the node until Ctrl-C / SIGTERM."""
    return run_node(IdentifierNode, 'identifier', num_threads=1, args=args)


if __name__ == '__main__':
    sys.exit(main())
