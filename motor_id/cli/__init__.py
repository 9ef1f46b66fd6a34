"""`motor-id` command line: parse, dispatch to the module that owns the subcommand, print.

Each subcommand has its own module in this package (parse, call the core, print); it exposes
``add_arguments(parser)`` and ``run(args) -> int``. Library errors (MotorIdError)
become one line on stderr and exit code 2, never a traceback. SIGTERM and SIGHUP stop a
command as Ctrl-C does (:func:`motor_id.lifeline.stop_signals_as_interrupt`): its
``finally`` blocks run (children stopped, files closed), and it exits with 130.
"""

import argparse
import gc
import importlib
import os
import sys

from motor_id.blas import limit_threads
from motor_id.errors import MotorIdError
from motor_id.lifeline import stop_signals_as_interrupt

COMMANDS = {
    'fit': ('motor_id.cli.fit', 'identify motor parameters from a CSV or MCAP recording'),
    'simulate': ('motor_id.cli.simulate', 'write simulated motor data to CSV'),
    'analyze': ('motor_id.cli.analyze', 'find what the linear model misses and extend it'),
    'validate': ('motor_id.cli.validate', 'score a saved model on another recording'),
    'card-sim': ('motor_id.cli.card_sim', 'run a simulated serial card on a pseudo-terminal'),
    'import': ('motor_id.cli.import_data', 'convert measured data (emps, dunker, csv) to MCAP'),
    'replay': ('motor_id.cli.replay', 'identify from a bag offline or republish it'),
    'bag': ('motor_id.cli.bag', 'inspect or recover an MCAP recording'),
    'demo': ('motor_id.cli.demo', 'simulated card + driver + identifier, end to end'),
    'fleet': ('motor_id.cli.fleet', 'every motor of every recording on Dask: histories, drift'),
    'experiment': ('motor_id.cli.experiment',
                   'identify a joint of a live ROS 2 robot through its controller, safely'),
}


def main(argv=None):
    """Console-script entry point (``python -m motor_id.cli`` too).

    Limits BLAS to one thread (:func:`motor_id.blas.limit_threads`) before a subcommand's
    module loads numpy.
    """
    limit_threads()
    from_console = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        module_name, help_text = COMMANDS[argv[0]]
        parser = argparse.ArgumentParser(prog=f'motor-id {argv[0]}', description=help_text)
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            print(f'motor-id {argv[0]}: not available ({exc})', file=sys.stderr)
            return 2
        module.add_arguments(parser)
        args = parser.parse_args(argv[1:])
        try:
            with stop_signals_as_interrupt():
                code = int(module.run(args) or 0)
            if from_console:
                # the process ends next: leave the ~10^5 objects that exist now (numba's
                # type system above all) to the OS instead of the interpreter's last
                # garbage collection at exit (~0.2 s of a 0.8 s `motor-id fit`)
                gc.freeze()
            return code
        except MotorIdError as exc:
            from motor_id.cli.flags import flag_hint
            hint = flag_hint(exc.params, parser.format_help())
            print(f'motor-id {argv[0]}: error: {exc}{hint}', file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f'motor-id {argv[0]}: interrupted', file=sys.stderr)
            return 130
        except BrokenPipeError:  # output piped into head & co.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
    parser = argparse.ArgumentParser(
        prog='motor-id', description='DC motor parameter identification (motor_id).',
        epilog='commands:\n' + '\n'.join(f'  {k:<10} {v[1]}' for k, v in COMMANDS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('command', choices=list(COMMANDS), help='see below')
    parser.parse_args(argv[:1])
    return 2

