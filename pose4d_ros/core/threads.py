"""Who owns the two cores: the BLAS thread count of the loaded OpenBLAS libraries.

numpy and scipy each ship an OpenBLAS (scipy's does the numba kernels' matrix products); its
thread pool is sized at load time from `OPENBLAS_NUM_THREADS` (default: all cores). These
helpers read and set it at run time through OpenBLAS's own C entry points (as threadpoolctl
does), so a process can choose after numpy has been imported. On the project's 2-core machine
the detector runs best with ONE BLAS thread and single-threaded numba (measured with `pose4d
bench`: a multi-threaded GEMM on 2 cores shared with the other pipeline stages is several times
slower, because its threads spin-wait for a core); see `core.dpm.infer`.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

_SETTERS = ('openblas_set_num_threads', 'scipy_openblas_set_num_threads64_',
            'openblas_set_num_threads64_', 'scipy_openblas_set_num_threads')
_GETTERS = ('openblas_get_num_threads', 'scipy_openblas_get_num_threads64_',
            'openblas_get_num_threads64_', 'scipy_openblas_get_num_threads')


def _openblas_libs() -> list[ctypes.CDLL]:
    import numpy  # noqa: F401  (make sure numpy's BLAS is loaded)
    import scipy.linalg.cython_blas  # noqa: F401  (and scipy's: the numba kernels' products)

    paths: list[str] = []
    try:
        for line in Path('/proc/self/maps').read_text().splitlines():
            parts = line.split()
            if len(parts) >= 6 and 'openblas' in parts[-1].lower() and parts[-1] not in paths:
                paths.append(parts[-1])
    except OSError:
        return []
    libs = []
    for p in paths:
        try:
            libs.append(ctypes.CDLL(p))
        except OSError:
            continue
    return libs


def _call(lib: ctypes.CDLL, names: tuple[str, ...], *args: int) -> int | None:
    for n in names:
        fn = getattr(lib, n, None)
        if fn is not None:
            return fn(*args)
    return None


def blas_threads() -> dict[str, int]:
    """{library file name: current thread count} of the OpenBLAS libraries loaded."""
    out = {}
    for lib in _openblas_libs():
        n = _call(lib, _GETTERS)
        if n is not None:
            out[Path(lib._name).name] = int(n)
    return out


def set_blas_threads(n: int) -> dict[str, int]:
    """Set every loaded OpenBLAS to `n` threads; returns the new {library: count}."""
    if n < 1:
        raise ValueError(f'BLAS threads must be >= 1, got {n}')
    for lib in _openblas_libs():
        fn = next((getattr(lib, s) for s in _SETTERS if getattr(lib, s, None) is not None), None)
        if fn is not None:
            fn.argtypes = [ctypes.c_int]
            fn(int(n))
    return blas_threads()
