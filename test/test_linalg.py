"""The batched matrix exponential against SciPy's."""

import numpy as np
import pytest
from scipy.linalg import expm as scipy_expm

from motor_id.linalg import expm


@pytest.mark.parametrize('n', [1, 2, 4, 6])
def test_expm_matches_scipy_on_random_and_stiff_batches(n):
    rng = np.random.default_rng(n)
    # plain, stiff (norms up to 1e6: many squarings) and tiny matrices, one batch
    scales = np.concatenate([np.ones(20), 10.0 ** rng.uniform(2, 6, 20),
                             10.0 ** rng.uniform(-12, -3, 20)])
    a = rng.normal(size=(60, n, n)) * scales[:, None, None]
    skew = 0.5 * (a[20:40] - np.swapaxes(a[20:40], 1, 2))
    a[20:40] = skew - np.eye(n) * scales[20:40, None, None] * 2  # stable stiff plants
    got = expm(a)
    want = np.array([scipy_expm(m) for m in a])
    err = np.abs(got - want) / (1.0 + np.abs(want).max(axis=(1, 2)))[:, None, None]
    assert err.max() < 1e-11


def test_expm_keeps_the_batch_shape_and_gives_nan_for_non_finite():
    a = np.zeros((3, 4, 2, 2))
    a[1, 2] = np.inf
    out = expm(a)
    assert out.shape == (3, 4, 2, 2)
    assert np.all(np.isnan(out[1, 2]))
    np.testing.assert_allclose(out[0, 0], np.eye(2), atol=0)


def test_expm_small_batch_uses_scipy_and_agrees():
    a = np.array([[[0.0, 1.0], [-2.0, -3.0]]])
    np.testing.assert_allclose(expm(a)[0], scipy_expm(a[0]), rtol=1e-14)
