"""Run small dense linear algebra single-threaded: the science does hundreds of SVDs of
~(300 x 50) to (3000 x 16) matrices, for which a multi-threaded OpenBLAS is 10-300x slower
than one thread on a loaded machine (threads wait for each other and for the cores).
Best effort through ctypes on numpy's bundled OpenBLAS; a no-op when it is not found."""
from __future__ import annotations

import contextlib
import ctypes
import glob
import os


def _lib():
    try:
        import numpy
        d = os.path.dirname(numpy.__file__)
        for path in glob.glob(os.path.join(d, "..", "numpy.libs", "*openblas*")) + \
                glob.glob(os.path.join(d, ".dylibs", "*openblas*")):
            lib = ctypes.CDLL(path)
            for get, set_ in (("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
                              ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
                              ("openblas_get_num_threads", "openblas_set_num_threads")):
                if hasattr(lib, get) and hasattr(lib, set_):
                    return getattr(lib, get), getattr(lib, set_)
    except Exception:
        pass
    return None


_FUNCS = _lib()


@contextlib.contextmanager
def single_thread():
    """Context manager that runs the enclosed block with OpenBLAS on one thread.

    On entry the current OpenBLAS thread count is read and set to 1; on exit
    (also on an exception) the previous count is restored.  When numpy's
    bundled OpenBLAS or its thread functions cannot be found, or the current
    count cannot be read, the block runs unchanged (a no-op).

    Yields
    ------
    None
        Control passes to the ``with`` block.

    Notes
    -----
    The thread count is process-wide, not thread-local: other threads doing
    linear algebra inside the block also run on one thread.
    """
    if _FUNCS is None:
        yield
        return
    get, set_ = _FUNCS
    try:
        n = int(get())
    except Exception:
        yield
        return
    set_(ctypes.c_int(1))
    try:
        yield
    finally:
        set_(ctypes.c_int(n))
