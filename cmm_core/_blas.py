"""One BLAS thread for the many small dense factorisations of this package.

The matrices here are small (a few hundred rows: one GP per error component, the normal
equations of a kinematic fit). Threaded OpenBLAS spends more time waking and synchronising
its threads than computing on them: on a 2-core machine the GP discrepancy of the thesis
data took 2.7 s with the default threads and 0.18 s with one (``bench/gp.py``). threadpoolctl
limits the threads of the already-loaded BLAS; without it this is a no-op.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

try:
    from threadpoolctl import threadpool_limits
except ImportError:  # pragma: no cover - threadpoolctl is in requirements.txt
    threadpool_limits = None

__all__ = ["single_blas_thread"]

P = ParamSpec("P")
R = TypeVar("R")


def single_blas_thread(func: Callable[P, R]) -> Callable[P, R]:
    """Decorator: run ``func`` with BLAS limited to one thread (nested calls are cheap).
    The decorated function keeps ``func``'s signature for the type checker; the
    undecorated one is ``inspect.unwrap(f)``."""

    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        if threadpool_limits is None:
            return func(*args, **kwargs)
        with threadpool_limits(limits=1, user_api="blas"):
            return func(*args, **kwargs)

    return wrapper
