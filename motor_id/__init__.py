"""motor_id: identify a DC motor's physical parameters from voltage, speed and current.

Importing the package sets ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` to 1 unless
they are already set, so that numpy and scipy, when they load after it (as in every
``motor-id``, ``driver`` and ``identifier`` process), use one BLAS thread. The matrices
here are small: more threads do not speed up a fit, and two busy processes whose BLAS
threads spin-wait for each other on a 2-core machine ran ``motor-id analyze`` 38 times
slower (141 s instead of 3.7 s). Set either variable to override.
"""

import os

for _var in ('OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
del _var

__version__ = '0.1.0'
