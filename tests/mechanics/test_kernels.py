"""The compiled kernels: cached on disk, and the law's element loop is the same as one element at a time."""

from __future__ import annotations

import numba
import numpy as np

from espin.mechanics import kernels
from espin.mechanics.fiber_law import FiberLaw, update


def test_every_kernel_is_cached_on_disk():
    """cache=True: the compile cost is paid once per install, not once per process."""
    jitted = [f for f in vars(kernels).values() if isinstance(f, numba.core.registry.CPUDispatcher)]
    assert len(jitted) >= len(kernels.__all__) - 2  # the two constants are not kernels
    for f in jitted:
        assert f.targetoptions["nogil"], f.__name__  # the law's threads run in parallel
        assert type(f._cache).__name__ == "FunctionCache", f.__name__


def test_power_matches_numpy_for_the_special_exponents():
    x = np.array([1e-6, 0.37, 1.0, 1.9, 1e3])
    for c in (0.0, 0.5, 1.0, 2.0, 0.3, 1.7):
        assert np.array_equal([kernels._power(v, c) for v in x], x**c), c


def test_threads_give_the_same_state_as_one_call():
    """The kernel holds no state between elements: chunks on threads equal one call."""
    from concurrent.futures import ThreadPoolExecutor

    law = FiberLaw(3000, 3, 1e-8, 5, 0.5)
    rng = np.random.default_rng(3)
    n = 40_000
    lam, lam_p, lam_r = rng.uniform(0.8, 1.4, n), 1 + rng.exponential(0.03, n), 1 + rng.exponential(0.05, n)
    whole = update(law, lam, lam_p, lam_r, 1.0)
    chunks = np.array_split(np.arange(n), 4)
    with ThreadPoolExecutor(2) as pool:
        parts = list(pool.map(lambda i: update(law, lam[i], lam_p[i], lam_r[i], 1.0), chunks))
    for name in ("stress", "plastic_stretch", "tangent", "recruited"):
        assert np.array_equal(np.concatenate([getattr(p, name) for p in parts]), getattr(whole, name))
