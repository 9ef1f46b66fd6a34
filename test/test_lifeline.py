"""Children that cannot outlive their parent; SIGTERM and SIGHUP as Ctrl-C; nothing left."""

import json
import os
import signal
import subprocess
import sys
import textwrap

import psutil
import pytest

from motor_id.lifeline import stop_signals_as_interrupt, tied
from motor_id.testing.procs import live_groups, Processes, wait_until
from motor_id.testing.ros import REPO

linux_only = pytest.mark.skipif(not sys.platform.startswith('linux'),
                                reason='the parent-death signal is Linux only')


def _gone(pid):
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


@linux_only
@pytest.mark.parametrize('how', [signal.SIGKILL, signal.SIGTERM])
def test_a_tied_child_gets_sigterm_when_its_parent_dies(tmp_path, how):
    """A parent starts a tied child that logs the signal it gets; the parent is killed
    (no cleanup of its own at all with SIGKILL): the child hears SIGTERM and ends."""
    log = tmp_path / 'child.log'
    child = textwrap.dedent(f"""
        import signal, sys, time
        def bye(signum, frame):
            open({str(log)!r}, 'w').write(signal.Signals(signum).name)
            sys.exit(0)
        signal.signal(signal.SIGTERM, bye)
        print('ready', flush=True)
        time.sleep(600)
    """)
    parent = textwrap.dedent(f"""
        import subprocess, sys, time
        from motor_id.lifeline import tied
        kid = subprocess.Popen(tied([sys.executable, '-c', {child!r}]), stdout=subprocess.PIPE)
        assert kid.stdout.readline().strip() == b'ready'
        print(kid.pid, flush=True)
        time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, '-c', parent], stdout=subprocess.PIPE,
                            env=dict(os.environ, PYTHONPATH=REPO))
    try:
        kid = int(proc.stdout.readline())
        assert not _gone(kid)
        proc.send_signal(how)
        assert proc.wait(30) == -how
        assert wait_until(lambda: _gone(kid), 30.0)
        assert log.read_text() == 'SIGTERM'
    finally:
        proc.kill()
        proc.wait()
        if not _gone(kid):
            os.kill(kid, signal.SIGKILL)


@linux_only
def test_a_tied_command_does_not_start_when_its_parent_is_already_gone(tmp_path):
    """The launcher runs after the parent died (here: it names another parent): no exec."""
    marker = tmp_path / 'ran'
    args = tied(['touch', str(marker)])
    pid_at = args.index(str(os.getpid()))
    args[pid_at] = str(os.getpid() + 1)              # not this launcher's parent
    assert subprocess.run(args, timeout=30).returncode == 128 + signal.SIGTERM
    assert not marker.exists()
    assert subprocess.run(tied(['touch', str(marker)]), timeout=30).returncode == 0
    assert marker.exists()
    missing = subprocess.run(tied(['no-such-command-here']), capture_output=True, text=True,
                             timeout=30)
    assert missing.returncode == 127 and 'cannot run' in missing.stderr


@linux_only
def test_a_worker_whose_parent_died_before_prctl_gets_the_signal_at_once():
    """set_parent_death_signal(parent=...): a parent other than the one named (it died
    before the signal was set, the worker went to init) ends the worker at once."""
    child = textwrap.dedent("""
        import os, signal, time
        from motor_id.lifeline import set_parent_death_signal
        assert set_parent_death_signal(signal.SIGTERM, parent=os.getppid())   # alive
        print('kept', flush=True)
        set_parent_death_signal(signal.SIGTERM, parent=os.getppid() + 1)   # "died"
        time.sleep(600)
    """)
    proc = subprocess.run([sys.executable, '-c', child], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=REPO), timeout=60)
    assert proc.returncode == -signal.SIGTERM and proc.stdout == 'kept\n', proc.stderr


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP])
def test_stop_signals_raise_keyboard_interrupt_then_the_handlers_come_back(sig):
    before = signal.getsignal(sig)
    with pytest.raises(KeyboardInterrupt, match=signal.Signals(sig).name):
        with stop_signals_as_interrupt():
            os.kill(os.getpid(), sig)
            for _ in range(10 ** 6):      # the handler runs between bytecodes
                pass
    assert signal.getsignal(sig) is before


def test_a_repeated_stop_signal_does_not_cut_the_cleanup_short():
    """The parent-death signal comes once per thread of a dying parent: the first
    SIGTERM interrupts, the repeats (SIGTERM or SIGHUP) do not."""
    cleaned = False
    with stop_signals_as_interrupt():
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10 ** 6):
                pass
        except KeyboardInterrupt:
            for sig in (signal.SIGTERM, signal.SIGTERM, signal.SIGHUP):
                os.kill(os.getpid(), sig)
            for _ in range(10 ** 6):      # the cleanup runs on
                pass
            cleaned = True
    assert cleaned


def test_an_ignored_sighup_stays_ignored():
    """``nohup`` ignores SIGHUP on purpose: a command keeps that."""
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with stop_signals_as_interrupt():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
            os.kill(os.getpid(), signal.SIGHUP)
    finally:
        signal.signal(signal.SIGHUP, previous)


# ---------------------------------------------------------------------------------------
# SignalThread: the signals heard off the main thread, and a deadline


def _watched(body, deadline):
    """A real process whose SignalThread logs its hooks, then runs ``body``."""
    script = textwrap.dedent(f"""
        import sys, threading
        from motor_id.lifeline import SignalThread
        log = lambda text: print(text, flush=True)
        SignalThread(on_stop=lambda sig: log(f'stop {{sig}}'),
                     last_resort=lambda: log('last resort: 0'),
                     deadline={deadline!r}).install()
        log('ready')
    """) + textwrap.dedent(body)
    return subprocess.Popen([sys.executable, '-c', script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONPATH=REPO))


def test_a_stuck_main_thread_is_ended_after_the_deadline_by_its_last_resort():
    """The main thread blocks for good (here on a lock it holds itself); SIGTERM: the
    stop hook runs at once, and at the deadline the last resort, then os._exit."""
    proc = _watched("""
        lock = threading.Lock()
        lock.acquire()
        lock.acquire()      # stuck for good
    """, deadline=1.0)
    try:
        assert proc.stdout.readline() == 'ready\n'
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)     # a failure bound
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert out.splitlines() == [f'stop {int(signal.SIGTERM)}', 'last resort: 0']
    assert 'still running 1 s after SIGTERM: ended' in err


def test_repeated_sigterms_are_ignored_and_a_second_sigint_ends_at_once():
    """The parent-death signal comes once per thread of a dying parent: repeats do not
    end the process (no deadline here), a second Ctrl-C does."""
    proc = _watched("""
        threading.Event().wait()
    """, deadline=None)
    try:
        assert proc.stdout.readline() == 'ready\n'
        proc.send_signal(signal.SIGTERM)
        assert proc.stdout.readline() == f'stop {int(signal.SIGTERM)}\n'
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGTERM):
            proc.send_signal(sig)
        assert proc.poll() is None
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 128 + signal.SIGINT, err
    assert out.splitlines() == ['last resort: 0'] and 'a second SIGINT: ended' in err


def test_processes_close_ends_every_child_and_whatever_they_left(tmp_path):
    """One child stops on SIGINT, one ignores it (killed after the timeout), one leaves
    a grandchild in its process group behind when it exits: after close, none is left."""
    stubborn = 'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); ' \
               'print("ready", flush=True); time.sleep(600)'
    leaver = 'import subprocess, sys; subprocess.Popen(["sleep", "600"]); ' \
             'print("ready", flush=True)'
    kids = Processes(dict(os.environ), tmp_path)
    py = sys.executable
    quiet = kids.start('quiet', [py, '-c', 'import time; print("ready", flush=True); '
                                 'time.sleep(600)'])
    hard = kids.start('stubborn', [py, '-c', stubborn])
    left = kids.start('leaver', [py, '-c', leaver])
    for proc in (quiet, hard, left):
        proc.wait_for('ready', 30.0)
    assert left.wait(30.0) == 0
    grandchild = [p for p in psutil.process_iter(['cmdline']) if p.info['cmdline'] ==
                  ['sleep', '600'] and os.getpgid(p.pid) == left.pid]
    assert len(grandchild) == 1 and left.pid in live_groups()
    kids.close(timeout=2.0)
    assert quiet.proc.returncode == -signal.SIGINT and not quiet.killed and hard.killed
    assert wait_until(lambda: _gone(grandchild[0].pid), 30.0)   # SIGKILL lands at once
    assert not {quiet.pid, hard.pid, left.pid} & set(live_groups())


def test_leftovers_names_and_kills_a_forgotten_child():
    """In a process of its own (here other tests' children may run): a forgotten child
    is named and killed, a burner is not, and then nothing is left."""
    script = textwrap.dedent("""
        import json, subprocess
        from motor_id.testing.procs import leftovers, start_burners
        burner = start_burners(1)[0]
        sleeper = subprocess.Popen(['sleep', '600'])
        first = leftovers()
        code = sleeper.wait(30)
        print(json.dumps([first, sleeper.pid, code, burner.poll(), leftovers()]))
        burner.kill()
    """)
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=REPO), timeout=120)
    first, pid, code, burner, after = json.loads(out.stdout)
    assert first == [f'{pid}: sleep 600'], out.stderr
    assert code == -signal.SIGKILL and burner is None and after == []


@linux_only
def test_forked_fit_workers_die_with_a_killed_caller():
    """The analysis's forked workers (motor-id analyze -j N) do not wait for tasks for ever
    when their caller is killed."""
    parent = textwrap.dedent("""
        import multiprocessing, os, time
        from motor_id.analysis.workers import _worker_start
        def pid(_):
            return os.getpid()
        pool = multiprocessing.get_context('fork').Pool(2, initializer=_worker_start)
        print(' '.join(str(p) for p in set(pool.map(pid, range(40), chunksize=1))),
              flush=True)
        time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, '-c', parent], stdout=subprocess.PIPE,
                            env=dict(os.environ, PYTHONPATH=REPO))
    try:
        workers = [int(p) for p in proc.stdout.readline().split()]
        assert workers and not any(_gone(w) for w in workers)
        proc.kill()
        assert proc.wait(30) == -signal.SIGKILL
        assert wait_until(lambda: all(_gone(w) for w in workers), 30.0)
    finally:
        proc.kill()
        proc.wait()


def test_a_ros_domain_leased_by_a_live_process_is_passed_over():
    """Two test runs on one machine must not share a ROS domain: a process whose first
    choice is leased by another live process takes the next free id; the same name keeps
    its id; two names in one process never share one."""
    from motor_id.testing.procs import domain_id
    mine = domain_id('lease-check')
    assert domain_id('lease-check') == mine and domain_id('lease-other') != mine
    script = textwrap.dedent(f"""
        import json
        from motor_id.testing import procs
        taken = procs.domain_lease({mine}) is None
        procs.os.getpid = lambda: {os.getpid()}   # the same first choice as the parent
        print(json.dumps([taken, procs.domain_id('lease-check')]))
    """)
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         env=dict(os.environ, PYTHONPATH=REPO), timeout=120)
    taken, theirs = json.loads(out.stdout)
    assert taken and theirs != mine, out.stderr


def test_the_run_passes_default_stop_signals_to_its_children():
    """Started under nohup or in the background, the run itself ignores SIGHUP or SIGINT
    (conftest), but by a handler, so its children get the default dispositions (their
    stop tests could not pass otherwise)."""
    script = 'import signal; print(int(signal.getsignal(signal.SIGHUP)), ' \
             'signal.getsignal(signal.SIGINT) is signal.default_int_handler)'
    out = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout.split() == [str(int(signal.SIG_DFL)), 'True'], out.stderr


EXIT_CHECK = """
import atexit, os, signal
def late():   # registered first, so it runs after the exit hooks of what follows
    print(*(signal.getsignal(s) is signal.SIG_IGN for s in (signal.SIGHUP, signal.SIGTERM)),
          flush=True)
    for s in (signal.SIGHUP, signal.SIGTERM):
        os.kill(os.getpid(), s)
atexit.register(late)
"""


@pytest.mark.parametrize('setup', [
    'from motor_id.lifeline import SignalThread\nSignalThread(deadline=None).install()',
    'from motor_id.lifeline import stop_signals_as_interrupt\n'
    'with stop_signals_as_interrupt():\n'
    '    try:\n'
    '        os.kill(os.getpid(), signal.SIGTERM)\n'
    '        signal.sigtimedwait([], 0.0)\n'
    '    except KeyboardInterrupt:\n'
    '        pass'])
def test_a_stop_signal_repeated_at_the_interpreters_exit_is_ignored(setup):
    """The interpreter's finalisation puts the default action back on a signal with a Python
    handler: a SIGHUP or SIGTERM repeated while a stopped node exits (a test's second one,
    a dying parent's parent-death signal per thread) ended it by the signal, exit -1, with
    every core busy. From the exit on both are ignored: a node's signal thread, and a CLI
    whose block got one of them."""
    out = subprocess.run([sys.executable, '-c', EXIT_CHECK + setup], capture_output=True,
                         text=True, env=dict(os.environ, PYTHONPATH=REPO), timeout=120)
    assert (out.returncode, out.stdout.split()) == (0, ['True', 'True']), out.stderr
