"""libigl's ARAP as the peer of the benchmarks (the optional extra `mvcjax[bench]`).

The same method as `benchmarks/table1.py`'s ARAP column (`igl.arap_precomputation` and
`igl.arap_solve`, the "elements" energy, 2D), on a rig's shape mesh with the shape vertex
each handle pins, for any number of iterations.
"""

from __future__ import annotations

import time


def igl_or_none():
    """The `igl` module, or `None` where libigl is not installed."""
    try:
        import igl
    except ImportError:
        return None
    return igl


def igl_version(igl) -> str:
    """libigl's installed version, or "missing"."""
    if igl is None:
        return "missing"
    import importlib.metadata

    return importlib.metadata.version("libigl")


def arap(igl, shape_mesh, iterations: int = 15):
    """libigl's ARAP on `shape_mesh` (a rig's `ShapeMesh`), its `handles` pinned:
    `(precompute seconds, solve)`, where `solve(pinned_targets, start)` returns the `(n,
    2)` result of `iterations` local-global steps from `start` (`(n, 2)`), the pinned
    vertices exactly at `pinned_targets` (`(r, 2)`, one per pinned row, as
    `rig.pinned_targets(targets)` gives them)."""
    import numpy as np

    vertices = np.ascontiguousarray(shape_mesh.vertices, np.float64)
    faces = np.ascontiguousarray(shape_mesh.faces, np.int64)
    handles = np.ascontiguousarray(shape_mesh.handles, np.int32)
    data = igl.ARAPData()
    data.max_iter = int(iterations)
    data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
    t0 = time.perf_counter()
    igl.arap_precomputation(vertices, faces, 2, handles, data)
    precompute = time.perf_counter() - t0

    def solve(pinned_targets, start):
        # arap_solve returns a new array; it does not write into the start.
        return igl.arap_solve(np.ascontiguousarray(pinned_targets, np.float64), data,
                              np.ascontiguousarray(start, np.float64))

    return precompute, solve
