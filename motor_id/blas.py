"""One BLAS thread per process, set by the entry points before numpy loads."""

import os

THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')
"""The environment variables that OpenBLAS and MKL read once, when numpy loads them."""


def limit_threads() -> None:
    """Set :data:`THREAD_VARIABLES` to 1 unless they are set already.

    Called first by every process's entry point: the ``motor-id`` command
    (:func:`motor_id.cli.main`), the nodes (importing :mod:`motor_id.nodes`, which every node
    process enters through) and the test suite (``test/conftest.py``); child processes
    (node processes, forked analysis workers, Dask workers, the benchmarks' fork server)
    inherit it. ``import motor_id`` leaves the environment alone.

    The matrices here are small: more threads do not speed up a fit, and two busy processes
    whose BLAS threads spin-wait for each other on a 2-core machine ran ``motor-id analyze``
    38 times slower (141 s instead of 3.7 s); two analyses of the paper's record side by
    side took 13.7 s each with the default threads, 4.7 s with one. It takes effect only
    when numpy has not been imported yet in this process; set either variable to override.
    """
    for var in THREAD_VARIABLES:
        os.environ.setdefault(var, '1')
