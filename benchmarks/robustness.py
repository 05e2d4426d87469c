"""Hostile input through mvcjax's public API: a fixed set of cases, each in a process of
its own with a time limit and a memory cap, and a table of what happened.

    python benchmarks/robustness.py [--quick] [--timeout S] [--only TEXT] [--json FILE]

Outcomes: "clear error" (a ValueError or TypeError raised by mvcjax itself), "accepted,
correct" (finite results that pass the case's check), "unclear error" (any other
exception, or one raised from inside a library), "NaN", "wrong answer", "hang" (past the
time limit), "crash" (the process died), "memory" (past the memory cap). The first two
are what mvcjax promises; the script prints the rest, and never fails on them.

The default check of a case that builds a rig: the rest targets give the rest shape,
and a rigid motion of the targets moves the result rigidly, to 1e-5 of the diagonal
(float32) or 1e-9 (float64).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import subprocess
import sys
import time
import traceback

OUTCOMES = ("clear error", "accepted, correct", "unclear error", "NaN", "wrong answer", "hang",
            "crash", "memory")


class Wrong(Exception):
    """A case's own check failed."""


class NotFinite(Wrong):
    """A result held NaN or infinite numbers."""


# ---- helpers the cases share (run in the child) -------------------------------------


def _np():
    import numpy as np

    return np


def x64():
    import jax

    jax.config.update("jax_enable_x64", True)


def star(points=10, inner=0.35, radius=1.0, offset=(0.0, 0.0)):
    np = _np()
    k = np.arange(points)
    r = np.where(k % 2 == 0, radius, inner * radius)
    a = k * 2 * np.pi / points
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1) + np.asarray(offset)


def rect(w, h):
    return _np().array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])


def finite(*arrays):
    np = _np()
    for a in arrays:
        if not np.all(np.isfinite(np.asarray(a))):
            raise NotFinite("non-finite values in the result")


def check_rig(rig, tol=None):
    """Rest in, rest out; rigid in, rigid out."""
    np = _np()
    import jax.numpy as jnp

    tol = (1e-9 if rig.shape_mesh.vertices.dtype == jnp.float64 else 1e-5) if tol is None else tol
    rest_shape = np.asarray(rig.shape_mesh.vertices, np.float64)
    diagonal = float(np.linalg.norm(rest_shape.max(0) - rest_shape.min(0)))
    spacing = float(np.spacing(np.abs(rest_shape).max() + diagonal))
    tol = max(tol, 8 * spacing / diagonal) * diagonal
    rest = np.asarray(rig.deform(rig.handle_positions), np.float64)
    finite(rest)
    if np.abs(rest - rest_shape).max() > tol:
        raise Wrong(f"rest targets miss the rest shape by {np.abs(rest - rest_shape).max():.3g} "
                    f"({np.abs(rest - rest_shape).max() / diagonal:.2g} of the diagonal)")
    handles = np.asarray(rig.handle_positions, np.float64)
    centre = handles.mean(axis=0)
    angle = np.pi / 6
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = 0.3 * diagonal
    moved = np.asarray(rig.deform((handles - centre) @ rot.T + centre + shift), np.float64)
    finite(moved)
    expected = (rest - centre) @ rot.T + centre + shift
    if np.abs(moved - expected).max() > 100 * tol:
        raise Wrong(f"a rigid motion of the targets moved the result by "
                    f"{np.abs(moved - expected).max() / diagonal:.2g} of the diagonal off rigid")
    return f"{rig.shape_mesh.vertices.shape[0]} shape vertices"


def build(outer, handles, holes=(), **kwargs):
    import mvcjax

    shape = mvcjax.Shape.from_polygon(outer, holes)
    return mvcjax.Rig.build(shape, handles, **kwargs)


def star_rig(**kwargs):
    return build(star(), [[0.0, 0.0], [0.4, 0.1]], **kwargs)


def converged_right(rig, targets, solver):
    """A solve that says it converged must be finite and near a long reference solve."""
    import mvcjax

    _, info = rig.solve(targets, solver, return_info=True)
    energy = float(info.energy)
    if bool(info.converged) and not _np().isfinite(energy):
        raise Wrong(f"converged=True at energy {energy}")
    reference = mvcjax.FixedG(iterations=20000, anderson=5, rtol=1e-9, stop_early=True)
    _, ref = rig.solve(targets, reference, return_info=True)
    if bool(info.converged) and energy > 1.01 * float(ref.energy) + 1e-12:
        raise Wrong(f"converged=True at energy {energy:.4g}, a longer solve reaches "
                    f"{float(ref.energy):.4g}")
    return f"converged={bool(info.converged)}, energy {energy:.4g}"


# ---- the cases ----------------------------------------------------------------------

CASES: dict[str, tuple[str, object, bool, float]] = {}


def case(group, quick=False, minutes=1.0):
    """Register a case: its group, whether the quick run has it, and its time limit in
    multiples of `--timeout`."""
    def register(fn):
        CASES[fn.__name__] = (group, fn, quick, minutes)
        return fn

    return register


@case("placement")
def star_at_origin():
    return check_rig(star_rig())


@case("placement", quick=True)
def star_at_1000_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(star(offset=(1000, 1000)), [[1000, 1000], [1000.4, 1000.1]],
                           dtype=jnp.float64))


@case("placement")
def star_at_1000_float32():
    return check_rig(build(star(offset=(1000, 1000)), [[1000, 1000], [1000.4, 1000.1]]))


@case("placement")
def star_at_300_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(star(offset=(300, 300)), [[300, 300], [300.4, 300.1]],
                           dtype=jnp.float64))


@case("placement")
def star_at_1e5_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(star(offset=(1e5, 1e5)), [[1e5, 1e5], [1e5 + 0.4, 1e5 + 0.1]],
                           dtype=jnp.float64))


@case("placement")
def star_scaled_1e_3_at_1_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(star(radius=1e-3, offset=(1, 1)), [[1, 1], [1.0004, 1.0001]],
                           dtype=jnp.float64))


@case("placement")
def random_star_diagonal_0_08_at_minus_300():
    x64()
    import jax.numpy as jnp

    np = _np()
    rng = np.random.default_rng(1)
    k = 14
    r = 0.04 * rng.uniform(0.5, 1.0, k)
    a = np.arange(k) * 2 * np.pi / k
    outer = np.stack([r * np.cos(a), r * np.sin(a)], axis=1) + [0.1, -300]
    return check_rig(build(outer, [[0.1, -300], [0.105, -300]], dtype=jnp.float64))


@case("placement")
def unit_square_at_1e5_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(rect(1, 1) + 1e5, [[1e5 + 0.3, 1e5 + 0.3], [1e5 + 0.7, 1e5 + 0.6]],
                           dtype=jnp.float64))


@case("placement")
def unit_square_at_1e5_float32():
    return check_rig(build(rect(1, 1) + 1e5, [[1e5 + 0.3, 1e5 + 0.3], [1e5 + 0.7, 1e5 + 0.6]]))


@case("placement")
def square_100_at_1e8_float64():
    x64()
    import jax.numpy as jnp

    return check_rig(build(rect(100, 100) + 1e8, [[1e8 + 30, 1e8 + 30], [1e8 + 70, 1e8 + 60]],
                           dtype=jnp.float64))


@case("placement", quick=True)
def star_scaled_1e_20():
    return check_rig(build(star(radius=1e-20), [[0, 0], [4e-21, 1e-21]]))


@case("placement")
def star_scaled_1e20():
    return check_rig(build(star(radius=1e20), [[0, 0], [4e19, 1e19]]))


@case("meshing")
def finer_spacing_gives_more_vertices():
    counts = [star_rig(shape_spacing=s).shape_mesh.vertices.shape[0] for s in (0.025, 0.0125)]
    if counts[1] <= counts[0]:
        raise Wrong(f"shape_spacing 0.0125 gave {counts[1]} vertices, 0.025 gave {counts[0]}")
    return f"{counts[0]} and {counts[1]} vertices"


@case("meshing")
def small_shape_gets_as_many_vertices():
    counts = [build(star(radius=r), [[0, 0], [0.4 * r, 0.1 * r]]).shape_mesh.vertices.shape[0]
              for r in (1.0, 1e-3)]
    if not 0.5 < counts[1] / counts[0] < 2:
        raise Wrong(f"{counts[1]} vertices at size 1e-3 against {counts[0]} at size 1")
    return f"{counts[0]} and {counts[1]} vertices"


@case("meshing", quick=True)
def spacing_asking_for_millions():
    build(rect(100, 100), [[50, 50]], shape_spacing=0.05)
    raise Wrong("built a mesh of millions of triangles without a word")


@case("meshing")
def margin_1e_9():
    import mvcjax

    return check_rig(star_rig(control=mvcjax.PaperControl(margin=1e-9)))


@case("polygons", quick=True)
def star_near_1e5_whose_last_point_is_near_its_first():
    import mvcjax

    shape = mvcjax.Shape.from_polygon(star(points=12, offset=(1e5, 1e5)))
    if len(shape.outer) != 12:
        raise Wrong(f"{len(shape.outer)} of 12 vertices kept")
    return "12 vertices"


@case("polygons")
def complex_polygon():
    import mvcjax

    mvcjax.Shape.from_polygon(star()[:, 0] + 1j * star()[:, 1])
    raise Wrong("accepted complex coordinates")


@case("polygons")
def boolean_polygon():
    import mvcjax

    mvcjax.Shape.from_polygon(rect(1, 1) > 0.5)
    raise Wrong("accepted a boolean polygon")


@case("polygons")
def string_polygon():
    import mvcjax

    mvcjax.Shape.from_polygon("square")
    raise Wrong("accepted a string")


@case("polygons")
def ragged_polygon():
    import mvcjax

    mvcjax.Shape.from_polygon([[0, 0], [1, 0, 2], [0, 1]])
    raise Wrong("accepted a ragged list")


@case("polygons", quick=True)
def shapely_polygon():
    import shapely

    import mvcjax

    polygon = shapely.Polygon(rect(2, 2), [rect(0.5, 0.5) + 0.5])
    shape = mvcjax.Shape.from_polygon(polygon)
    if abs(shape.area - polygon.area) > 1e-9:
        raise Wrong(f"area {shape.area}, expected {polygon.area}")
    return "accepted"


@case("polygons")
def shapely_multipolygon():
    import shapely

    import mvcjax

    mvcjax.Shape.from_polygon(shapely.MultiPolygon([shapely.Polygon(rect(1, 1)),
                                                    shapely.Polygon(rect(1, 1) + 3)]))
    raise Wrong("picked a part of a MultiPolygon silently")


@case("masks", quick=True)
def nan_in_float_mask():
    import mvcjax

    mask = _np().zeros((20, 20))
    mask[5:15, 5:15] = 1
    mask[0, 0] = _np().nan
    mvcjax.Shape.from_image(mask)
    raise Wrong("accepted NaN pixels")


@case("masks")
def complex_mask():
    import mvcjax

    mask = _np().zeros((20, 20), complex)
    mask[5:15, 5:15] = 1
    mvcjax.Shape.from_image(mask)
    raise Wrong("accepted a complex mask")


@case("masks")
def string_mask():
    import mvcjax

    mvcjax.Shape.from_image(_np().full((20, 20), "x"))
    raise Wrong("accepted a string mask")


def _square_mask():
    mask = _np().zeros((20, 20), bool)
    mask[5:15, 5:15] = True
    return mask


@case("masks")
def tolerance_nan():
    import mvcjax

    mvcjax.Shape.from_image(_square_mask(), tolerance=float("nan"))
    raise Wrong("accepted tolerance=nan")


@case("masks")
def tolerance_negative():
    import mvcjax

    mvcjax.Shape.from_image(_square_mask(), tolerance=-1.0)
    raise Wrong("accepted tolerance=-1")


@case("masks")
def min_hole_area_nan():
    import mvcjax

    mvcjax.Shape.from_image(_square_mask(), min_hole_area=float("nan"))
    raise Wrong("accepted min_hole_area=nan")


@case("masks")
def component_float():
    import mvcjax

    mvcjax.Shape.from_image(_square_mask(), component=1.5)
    raise Wrong("accepted component=1.5")


@case("masks")
def one_pixel_line_mask():
    import mvcjax

    mask = _np().zeros((20, 40), bool)
    mask[10, 5:35] = True
    shape = mvcjax.Shape.from_image(mask)
    if shape.area < 0.9 * 29:
        raise Wrong(f"area {shape.area:.3g} for a line of 30 pixels")
    return check_rig(mvcjax.Rig.build(shape, [[10.0, 9.0], [30.0, 9.0]]))


@case("dtypes", quick=True)
def float64_without_x64():
    import jax.numpy as jnp

    star_rig(dtype=jnp.float64)
    raise Wrong("a float64 rig without jax_enable_x64")


@case("dtypes")
def integer_dtype():
    star_rig(dtype=int)
    raise Wrong("an integer rig")


@case("dtypes")
def float16_dtype():
    import jax.numpy as jnp

    star_rig(dtype=jnp.float16)
    raise Wrong("a float16 rig")


@case("dtypes")
def bfloat16_dtype():
    import jax.numpy as jnp

    star_rig(dtype=jnp.bfloat16)
    raise Wrong("a bfloat16 rig")


@case("dtypes")
def complex_dtype():
    import jax.numpy as jnp

    star_rig(dtype=jnp.complex64)
    raise Wrong("a complex rig")


@case("arguments", quick=True)
def control_an_int():
    star_rig(control=3)
    raise Wrong("accepted control=3")


@case("arguments")
def control_faces_out_of_range():
    import mvcjax

    star_rig(control=mvcjax.GivenControl(star(), _np().array([[0, 1, 99]])))
    raise Wrong("accepted faces out of range")


@case("arguments")
def ragged_handles():
    build(star(), [[0, 0], [0.4]])
    raise Wrong("accepted ragged handles")


@case("arguments")
def string_handles():
    build(star(), "centre")
    raise Wrong("accepted string handles")


@case("arguments")
def handle_outside():
    build(star(), [[5.0, 5.0]])
    raise Wrong("accepted a handle outside the shape")


@case("arguments")
def duplicated_handles():
    build(star(), [[0.1, 0.1], [0.1, 0.1]])
    raise Wrong("accepted two handles on one spot")


@case("arguments")
def weights_a_dict():
    star_rig(weights={"handle": 10.0})
    raise Wrong("accepted a dict of weights")


@case("solvers", quick=True)
def fixed_g_iterations_float():
    import mvcjax

    star_rig().deform(star_rig().handle_positions, mvcjax.FixedG(iterations=2.0))
    raise Wrong("accepted iterations=2.0")


@case("solvers")
def fixed_g_iterations_zero():
    import mvcjax

    mvcjax.FixedG(iterations=0)
    raise Wrong("accepted iterations=0")


def _negative_tolerances(solver):
    import mvcjax

    rig = star_rig()
    targets = _np().asarray(rig.handle_positions) + [[0.3, 0.0], [0.0, 0.0]]
    return converged_right(rig, targets, getattr(mvcjax, solver)(rtol=-1, atol=-1))


@case("solvers", quick=True)
def gauss_newton_negative_tolerances():
    return _negative_tolerances("GaussNewton")


@case("solvers")
def levenberg_marquardt_negative_tolerances():
    return _negative_tolerances("LevenbergMarquardt")


@case("solvers")
def dogleg_negative_tolerances():
    return _negative_tolerances("Dogleg")


@case("solvers")
def gauss_newton_nan_tolerance():
    import mvcjax

    mvcjax.GaussNewton(rtol=float("nan"))
    raise Wrong("accepted rtol=nan")


@case("solvers")
def gauss_newton_negative_max_steps():
    import mvcjax

    mvcjax.GaussNewton(max_steps=-1)
    raise Wrong("accepted max_steps=-1")


@case("solvers")
def grad_through_stop_early():
    import jax
    import jax.numpy as jnp

    import mvcjax

    rig = star_rig()
    solver = mvcjax.FixedG(iterations=2000, rtol=1e-6, stop_early=True)
    g = jax.grad(lambda t: jnp.sum(rig.deform(t, solver)[::5] ** 2))(rig.handle_positions + 0.1)
    finite(g)
    return "gradient"


@case("weights", quick=True)
def weights_all_shape_terms_zero():
    import mvcjax

    check_rig(star_rig(weights=mvcjax.Weights.paper(laplacian=0, mvc=0, length=0)))
    return "solved"


@case("weights")
def weights_handle_1e_30():
    import mvcjax

    return check_rig(star_rig(weights=mvcjax.Weights(handle=1e-30)))


@case("weights")
def weights_length_1e20():
    import mvcjax

    return check_rig(star_rig(weights=mvcjax.Weights.paper(length=1e20)))


@case("weights")
def weights_handle_1e30():
    import mvcjax

    rig = star_rig(weights=mvcjax.Weights(handle=1e30))
    return converged_right(rig, rig.handle_positions + 0.2, mvcjax.GaussNewton())


@case("weights")
def weights_all_1e_30():
    x64()
    import jax.numpy as jnp

    import mvcjax

    rig = star_rig(weights=mvcjax.Weights(mvc=1e-34, handle=1e-30, arap=1e-30),
                   dtype=jnp.float64)
    targets = _np().asarray(rig.handle_positions) + [[0.3, 0.0], [0.0, 0.0]]
    return converged_right(rig, targets, mvcjax.GaussNewton())


@case("targets", quick=True)
def target_at_1e20():
    import mvcjax

    rig = star_rig()
    targets = _np().asarray(rig.handle_positions).copy()
    targets[0] = 1e20
    _, info = rig.solve(targets, mvcjax.GaussNewton(), return_info=True)
    if bool(info.converged) and not _np().isfinite(float(info.energy)):
        raise Wrong(f"converged=True at energy {float(info.energy)}")
    return f"converged={bool(info.converged)}"


@case("targets")
def targets_with_nan():
    rig = star_rig()
    rig.deform(_np().full((2, 2), _np().nan))
    raise Wrong("accepted NaN targets")


@case("targets")
def complex_targets():
    rig = star_rig()
    rig.deform(_np().asarray(rig.handle_positions) + 1j)
    raise Wrong("accepted complex targets")


@case("targets")
def targets_closed_over_in_jit():
    import jax

    rig = star_rig()
    t = rig.handle_positions + 0.05
    out = jax.jit(lambda: rig.deform(t))()
    if _np().abs(_np().asarray(out) - _np().asarray(rig.deform(t))).max() > 1e-5:
        raise Wrong("jit and eager differ")
    return "same as eager"


@case("targets")
def with_weights_under_jit():
    import jax

    import mvcjax

    rig = star_rig()
    t = rig.handle_positions + 0.05
    out = jax.jit(lambda w: rig.with_weights(mvcjax.Weights(arap=w)).deform(t))(1.0)
    finite(out)
    return "finite"


@case("frames", quick=True)
def frames_with_one_nan_frame():
    import mvcjax

    rig = star_rig()
    frames = _np().repeat(_np().asarray(rig.handle_positions)[None], 5, axis=0)
    frames[2, 0, 0] = _np().nan
    out = mvcjax.deform_frames(rig, frames)
    finite(out)
    return "finite"


@case("frames")
def frames_chunk_float():
    import mvcjax

    rig = star_rig()
    mvcjax.deform_frames(rig, rig.handle_positions[None].repeat(4, 0), chunk=2.5)
    raise Wrong("accepted chunk=2.5")


@case("frames")
def frames_no_devices():
    import mvcjax

    rig = star_rig()
    mvcjax.deform_frames(rig, rig.handle_positions[None].repeat(4, 0), devices=[])
    raise Wrong("accepted devices=[]")


@case("thin shapes", quick=True)
def bar_1000_by_0_01():
    return check_rig(build(rect(1000, 0.01), [[1, 0.005], [999, 0.005]]))


@case("thin shapes")
def rectangle_100_by_1e_6():
    return check_rig(build(rect(100, 1e-6), [[1, 5e-7], [99, 5e-7]]))


@case("thin shapes")
def triangle_1e_6_high():
    return check_rig(build(_np().array([[0, 0], [1, 0], [0.5, 1e-6]]), [[0.5, 5e-7]]))


@case("thin shapes")
def triangle_of_subnormal_height():
    return check_rig(build(_np().array([[0, 0], [1, 0], [0.5, 1e-310]]), [[0.5, 0.0]]))


@case("thin shapes")
def square_with_thin_spike():
    outer = _np().array([[0, 0], [1, 0], [1, 1], [0.5005, 1], [0.5005, 1.5], [0.4995, 1.5],
                         [0.4995, 1], [0, 1]])
    return check_rig(build(outer, [[0.2, 0.2], [0.8, 0.8]]))


@case("thin shapes", quick=True)
def comb_with_narrow_slots():
    import shapely

    poly = shapely.box(0, 0, 8 * 0.11, 0.2)
    for i in range(8):
        poly = poly.union(shapely.box(i * 0.11, 0.2, i * 0.11 + 0.1, 1.0))
    outer = _np().asarray(poly.exterior.coords)[:-1]
    return check_rig(build(outer, [[0.05, 0.1], [0.05, 0.9], [0.82, 0.9]]))


def built_within(seconds, outer, handles):
    """`check_rig` of the rig built from `outer`, if `Rig.build` took at most `seconds`."""
    start = time.perf_counter()
    rig = build(outer, handles)
    took = time.perf_counter() - start
    if took > seconds:
        raise Wrong(f"Rig.build took {took:.1f} s, over {seconds} s")
    return f"built in {took:.1f} s; " + check_rig(rig)


@case("thin shapes")
def comb_of_40_points_with_0_001_slots():
    np = _np()
    outer = [(0, 1), (0, -1)]
    for x in np.arange(1, 10) / 10:
        outer += [(x - 5e-4, -1), (x - 5e-4, 0), (x + 5e-4, 0), (x + 5e-4, -1)]
    outer = np.array(outer[:-4] + [(1, -1), (1, 1)], float)
    return built_within(10, outer, [[0.5, 0.5], [0.05, -0.9]])


@case("thin shapes")
def star_of_200_lobes_in_100000_points():
    np = _np()
    t = np.linspace(0, 2 * np.pi, 100_000, endpoint=False)
    r = 1 + 0.3 * np.sin(200 * t)
    return built_within(10, np.stack([r * np.cos(t), r * np.sin(t)], axis=1), [[0, 0], [0.5, 0]])


@case("thin shapes")
def strip_1e4_by_1():
    return check_rig(build(rect(1e4, 1), [[10, 0.5], [9990, 0.5]]))


@case("thin shapes", quick=True)
def holes_touching_at_a_point():
    np = _np()
    holes = [np.array([[40, 40], [60, 40], [60, 60], [40, 60.0]]),
             np.array([[60, 60], [80, 60], [80, 80], [60, 80.0]])]
    return check_rig(build(rect(100, 100), [[20.0, 20.0]], holes))


@case("thin shapes")
def hole_touching_the_outline():
    hole = _np().array([[0, 40], [20, 30], [20, 50.0]])
    return check_rig(build(rect(100, 100), [[60.0, 60.0]], [hole]))


@case("thin shapes")
def circle_of_100000_points():
    np = _np()
    t = np.linspace(0, 2 * np.pi, 100_000, endpoint=False)
    return check_rig(build(np.stack([np.cos(t), np.sin(t)], axis=1), [[0, 0], [0.5, 0]]))


@case("thin shapes")
def spiral():
    import shapely

    t = _np().linspace(0, 4 * _np().pi, 400)
    line = shapely.LineString(_np().stack([t * _np().cos(t), t * _np().sin(t)], axis=1))
    outer = _np().asarray(line.buffer(0.8).exterior.coords)[:-1]
    return check_rig(build(outer, [[0.0, 0.0], [12.5, 0.0]]))


@case("thin shapes")
def handle_on_a_hole_edge():
    hole = rect(20, 20) + 40
    return check_rig(build(rect(100, 100), [[40.0, 50.0], [10.0, 10.0]], [hole]))


@case("sessions", minutes=5.0)
def many_rigs_keep_memory_flat():
    import mvcjax

    def maps():
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)

    counts = []
    for k in range(150):
        s = 1.0 + k
        rig = build(rect(1, 1) * s + 3 * k, (_np().array([[0.25, 0.25], [0.75, 0.25]]) * s
                                             + 3 * k), shape_spacing=0.2 * s)
        rig.deform(rig.handle_positions + 0.01 * s)
        rig.solve(rig.handle_positions, mvcjax.GaussNewton())
        if k in (9, 149):
            counts.append(maps())
    if counts[1] > 2 * counts[0]:
        raise Wrong(f"memory maps grew from {counts[0]} (rig 10) to {counts[1]} (rig 150)")
    return f"memory maps {counts[0]} after 10 rigs, {counts[1]} after 150"


# ---- running them -------------------------------------------------------------------


def run_in_child(name: str) -> dict:
    """Run one case here and classify what happened."""
    _, fn, _, _ = CASES[name]
    start = time.perf_counter()
    try:
        message = fn()
        outcome = "accepted, correct"
    except NotFinite as error:
        outcome, message = "NaN", str(error)
    except Wrong as error:
        outcome, message = "wrong answer", str(error)
    except MemoryError as error:
        outcome, message = "memory", f"MemoryError: {error}"
    except Exception as error:
        import mvcjax

        frames = traceback.extract_tb(error.__traceback__)
        raised_in = frames[-1].filename if frames else ""
        ours = raised_in.startswith(os.path.dirname(mvcjax.__file__) + os.sep)
        clear = isinstance(error, (ValueError, TypeError)) and ours
        outcome = "clear error" if clear else "unclear error"
        message = f"{type(error).__name__}: {error}"
    return {"outcome": outcome, "message": str(message).splitlines()[0][:300] if message else "",
            "seconds": round(time.perf_counter() - start, 2)}


def _limit_memory(gib: float):
    def apply():
        limit = int(gib * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return apply


def run_case(name: str, timeout: float, memory_gib: float) -> dict:
    group, _, _, minutes = CASES[name]
    timeout = timeout * minutes
    start = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, __file__, "--child", name], capture_output=True,
                              text=True, timeout=timeout, preexec_fn=_limit_memory(memory_gib))
    except subprocess.TimeoutExpired:
        return {"case": name, "group": group, "outcome": "hang",
                "seconds": round(time.perf_counter() - start, 1),
                "message": f"no result after {timeout:.0f} s"}
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode == 0 and lines:
        result = json.loads(lines[-1])
    else:
        tail = (proc.stderr.strip().splitlines() or [""])[-1]
        memory = "MemoryError" in proc.stderr or "Unable to allocate" in proc.stderr
        result = {"outcome": "memory" if memory else "crash",
                  "message": f"exit {proc.returncode}: {tail[:200]}"}
    result.update(case=name, group=group, seconds=round(time.perf_counter() - start, 1))
    return result


def format_table(results: list[dict]) -> str:
    """The markdown table of the outcomes' counts, and how many cases kept the promise."""
    counts = collections.Counter(r["outcome"] for r in results)
    lines = ["| outcome | cases |", "|---|---|"]
    lines += [f"| {outcome} | {counts.get(outcome, 0)} |" for outcome in OUTCOMES]
    bad = [r for r in results if r["outcome"] not in ("clear error", "accepted, correct")]
    lines += ["", f"{len(results) - len(bad)} of {len(results)} cases kept mvcjax's promise."]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a subset of a few minutes")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds per case")
    parser.add_argument("--memory-gib", type=float, default=8.0, help="memory cap per case")
    parser.add_argument("--only", default="", help="run the cases whose name contains this")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(run_in_child(args.child)), flush=True)
        return 0

    names = [n for n, (_, _, quick, _) in CASES.items()
             if (quick or not args.quick) and args.only in n]
    results = []
    width = max(len(n) for n in names)
    for name in names:
        result = run_case(name, args.timeout, args.memory_gib)
        results.append(result)
        print(f"{result['group']:<12} {name:<{width}}  {result['outcome']:<18} "
              f"{result['seconds']:>6.1f} s  {result['message'][:110]}", flush=True)

    counts = collections.Counter(r["outcome"] for r in results)
    print()
    print(format_table(results))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"cases": results, "counts": dict(counts)}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
