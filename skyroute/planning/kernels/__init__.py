"""The compiled loops (numba) under every planner, one module per idea:

==============  ==================================================================================================
module          what it holds
==============  ==================================================================================================
``heap``        binary min-heap of ``(f, g, node)`` shared by every search
``table``       per-query search state in a hash table (memory grows with the cells touched, not the grid)
``bits``        the grid as bits (rows and transposed columns) for 64-cells-a-word straight scans
``gridsearch``  textbook A* and jump point search on the padded, flattened occupancy grid
``lines``       the supercover walk of a segment (line of sight) and line-of-sight pruning
``raster``      obstacle footprints grown by a Euclidean margin, rasterised row by row
==============  ==================================================================================================

Every kernel is compiled with ``cache=True``: numba stores the machine code on disk beside the source, so only
the first run in a fresh environment compiles (a few seconds); :func:`on_first_compile` lets the command line
say so while it happens.

Importing numba the usual way also imports SciPy (numba's version check, and ``scipy.linalg`` to see whether
``np.convolve`` may call BLAS) and cffi, which cost more than a whole plan on the SF map. None of our kernels uses
either, so this package imports numba with both hidden (:func:`_import_numba_without_scipy`); SciPy imports
normally later for the planners that use it, and numba's own linear-algebra functions still import it when
compiled.
Other compiled modules take ``njit`` from here (``kernels.njit``) so that this import always comes first.
"""

from __future__ import annotations

import sys
from collections.abc import Callable


def _import_numba_without_scipy() -> None:
    """Import numba and its NumPy and cffi support with ``scipy`` and ``cffi`` hidden, if numba is not loaded yet.

    Hidden, ``import scipy`` and ``import cffi`` raise ImportError, which numba handles: it skips its SciPy version
    check, sets ``numba.np.arraymath._HAVE_BLAS = False`` (``np.convolve``/``np.correlate`` inside jitted code then
    use a plain loop) and leaves cffi functions untyped; none of our kernels uses either. The entries are removed
    again at once, so later imports of SciPy (by the graph planners) and cffi work as usual.
    """
    if "numba" in sys.modules:
        return
    hidden = [name for name in ("scipy", "cffi") if name not in sys.modules]
    for name in hidden:
        sys.modules[name] = None  # type: ignore[assignment]
    try:
        import numba  # noqa: F401
        import numba.core.typing.cffi_utils  # noqa: F401
        import numba.np.arraymath  # noqa: F401
    finally:
        for name in hidden:
            del sys.modules[name]


_import_numba_without_scipy()

from numba import njit  # noqa: E402
from numba.core import event  # noqa: E402

from skyroute.planning.kernels.bits import pack_columns, pack_rows, scan_tables  # noqa: E402
from skyroute.planning.kernels.gridsearch import SQRT2, astar, jps, octile, weighted_astar  # noqa: E402
from skyroute.planning.kernels.heap import heap_pop, heap_push, new_heap  # noqa: E402
from skyroute.planning.kernels.lines import prune_los_mask, walk_supercover  # noqa: E402
from skyroute.planning.kernels.raster import rasterise, rasterise_max  # noqa: E402

__all__ = [
    "SQRT2", "astar", "heap_pop", "heap_push", "jps", "new_heap", "njit", "octile",
    "on_first_compile", "pack_columns", "pack_rows", "prune_los_mask", "rasterise", "rasterise_max", "scan_tables",
    "walk_supercover", "weighted_astar",
]


class _CompileWatch(event.Listener):
    """Calls the callback given to :func:`on_first_compile` when numba next starts compiling (loading a kernel
    from the disk cache is not compiling)."""

    def __init__(self) -> None:
        self.callback: Callable[[], None] | None = None

    def on_start(self, ev) -> None:
        callback, self.callback = self.callback, None
        if callback is not None:
            callback()

    def on_end(self, ev) -> None:
        pass


_watch = _CompileWatch()
event.register("numba:compile", _watch)


def on_first_compile(callback: Callable[[], None] | None) -> None:
    """Call ``callback()`` once, when numba next starts compiling a kernel (none of them is in the disk cache:
    a fresh install or changed source). ``None`` cancels."""
    _watch.callback = callback

