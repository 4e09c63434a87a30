"""Intel MKL (PARDISO and its thread controls), loaded once per process.

The PARDISO backend of the linear solvers calls it; the task pool loads it before a task so
that a thread limit reaches MKL's threads too.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

from espin.core.errors import ConfigError

__all__ = ["MKL", "load_mkl"]


@dataclass(frozen=True)
class MKL:
    """MKL's ``pardiso`` function and thread controls (see :func:`load_mkl`)."""

    pardiso: Callable[..., None]
    set_num_threads_local: Callable[[int], int]
    get_max_threads: Callable[[], int]


@cache
def load_mkl() -> MKL:
    """Load MKL once per process through pypardiso's search for ``mkl_rt``.

    Raises
    ------
    ConfigError
        If pypardiso is not installed or finds no MKL.

    Notes
    -----
    Sets ``KMP_BLOCKTIME=0`` unless the environment has it: MKL's OpenMP threads then sleep
    as soon as a factorization ends instead of spinning for 200 ms on the cores that the
    fiber law and assembly need between factorizations (plla tensile test: 54.7 s -> 48.8 s
    on 2 cores). It acts only if this loads the OpenMP runtime, as it does in espin.

    Sets ``MKL_CBWR=AUTO`` unless the environment has it: MKL's conditional numerical
    reproducibility, so that the same matrix factorizes to the same bits in every process.
    Without it MKL's kernels depend on how the arrays happen to be aligned in memory: the
    same plla test with a Poisson lateral condition ended 1e-15 apart in three processes, and
    a bonded mat at plla size with free sides took 40 Newton iterations in one run and stalled
    for 608 in the next. It acts only if this loads MKL, as it does in espin.
    """
    os.environ.setdefault("KMP_BLOCKTIME", "0")
    os.environ.setdefault("MKL_CBWR", "AUTO")
    try:
        from pypardiso.pardiso_wrapper import PyPardisoSolver

        library = PyPardisoSolver().libmkl
    except (ImportError, OSError) as exc:
        raise ConfigError(
            "the 'pardiso' linear solver needs the pypardiso package and Intel MKL "
            f"(x86-64 only): {exc}; use 'superlu' or 'auto'"
        ) from exc
    pardiso = library["pardiso"]  # a function object of our own: its argtypes are ours
    int_p = ctypes.POINTER(ctypes.c_int32)  # MKL_INT of the default LP64 interface
    void_p = ctypes.c_void_p
    # pt maxfct mnum mtype phase n a ia ja perm nrhs iparm msglvl b x error
    pardiso.argtypes = [
        void_p,
        int_p,
        int_p,
        int_p,
        int_p,
        int_p,
        void_p,
        int_p,
        int_p,
        int_p,
        int_p,
        int_p,
        int_p,
        void_p,
        void_p,
        int_p,
    ]
    pardiso.restype = None
    return MKL(pardiso, library.MKL_Set_Num_Threads_Local, library.MKL_Get_Max_Threads)
