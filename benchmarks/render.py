"""Render time per frame: `mvcjax.Renderer` on the horse, against its peers and a loop.

Three parts, each in the same run, float32 on whatever JAX device is the default:

- render: for each shape mesh (about 6k and 20k vertices) and output size (256, 512 and
  1024 pixels square), the renderer's tile and budget, the compile time of a frame,
  the median time of one jitted frame (antialiased, and without antialiasing), of a
  batch of B frames through `jax.jit(jax.vmap(renderer))`, of `Renderer.frames`' way
  (`jax.lax.map` in one program) and of a Python loop of the jitted single frame over
  the same B frames (dispatched asynchronously, blocked once at the end), these three
  timed in turns (`interleaved_median_ms`), and their ratios. The horse is drawn with the
  checkerboard fill, posed by the demo's drag at 0.2 to 1 of its length.
- peer: one pose (the drag at 0.3 of its length: no flipped triangle, and the lifted
  front leg not yet over the other one, which matplotlib's triangulation refuses) drawn
  with a painted picture (scikit-image's astronaut, resized onto the horse's rest
  window) by mvcjax, by scikit-image (`PiecewiseAffineTransform` estimated from the
  deformed to the rest vertices, then `warp`, bilinear) and by matplotlib
  (`LinearTriInterpolator` of the rest positions over the deformed mesh at every pixel
  centre, then `scipy.ndimage.map_coordinates`, bilinear). Each peer's time, and its
  ratio to mvcjax's frame; the pixels' agreement (premultiplied RGBA, 0..1) where the
  pixel centre lies inside the deformed silhouette and at least 2 pixels from its
  outline, and how the edges differ. The error of mvcjax's texture positions, in
  texels, is measured by drawing a linear ramp instead of the picture.
- layers: a layered character of 3 to 8 parts (a disc of a body with limbs on layers
  of their own, each lying over the body at its root and pinned by a bone from inside
  the body to its tip; about 6k shape vertices in all), drawn at 512 x 512 with the
  limbs turned: the build's time, the compile and median times of one jitted frame's
  pose (`Character.deform`) and picture (`CharacterRenderer`), and the same for the
  same figure as one silhouette (its layers flattened, one rig and one renderer, meshed
  to as many shape vertices), with the ratios of the two.
- export: an animation of the horse dragged there and back, 256 x 256, written by
  `mvcjax.export.write_animation` as GIF, animated PNG, WebP and MP4: seconds and bytes.

With `--baseline REF`, the 512 x 512 frame at 6k vertices and each layered character's
picture are also timed in turns (`interleaved_median_ms`) against the renderer's
drawing as it was at git commit REF, on the same renderer and poses: a
before-and-after ratio measured in one run, which holds however busy the machine is.

Times are medians over many calls after one compiling call (compile time reported
apart), every call blocked until ready; each ratio is of two times measured in this
run. The targets (512 x 512 at 6k vertices in at most 8 ms a frame; `jax.vmap(renderer)`
at least 0.9 times the throughput of `Renderer.frames`) are printed and recorded with
whether they were met, never asserted.

    python benchmarks/render.py                       # 6k and 20k; 256, 512, 1024; 200 frames
    python benchmarks/render.py --quick --json FILE   # 6k; 256, 512; peers at 256; 12 frames;
                                                      # 3 and 8 parts
    python benchmarks/render.py --baseline REF        # and the 512, 6k frame and the
                                                      # layered pictures against REF's
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
import warnings

from _timing import compile_ms, interleaved_median_ms, median_ms, spacing_for, write_results

VERTICES = [6000, 20000]
SIZES = [256, 512, 1024]
QUICK_VERTICES = [6000]
QUICK_SIZES = [256, 512]
PEER_SIZES = [512]
QUICK_PEER_SIZES = [256]
# In quick mode the peers draw a 1.5k-vertex mesh: scikit-image's estimate fits a
# transform per triangle, and its warp loops over the triangles in Python.
QUICK_PEER_VERTICES = 1500
EXPORT_FRAMES, QUICK_EXPORT_FRAMES = 200, 12
LAYER_PARTS, QUICK_LAYER_PARTS = [3, 5, 8], [3]
LAYER_CANVAS, LAYER_VERTICES = 256, 6000  # pixels square; shape vertices in all
EXPORT_SIZE = 256
FORMATS = [".gif", ".png", ".webp", ".mp4"]

TARGET_FRAME_MS = 8.0  # 512 x 512 at 6k vertices, one frame
TARGET_SIZE, TARGET_VERTICES = 512, 6000
# jax.vmap(renderer) as fast as Renderer.frames (lax.map), within run-to-run noise.
TARGET_VMAP_OVER_MAP = 0.9
PEER_DRAG = 0.3  # of the demo drag: from about 0.375 the lifted front leg overlaps the other
INSIDE_PIXELS = 2.0  # agreement is measured this far inside the outline, in pixels


def _batch(size: int, quick: bool) -> int:
    if quick:
        return 4
    return 4 if size >= 1024 else 16


def _rig_of(shape, vertices: int, rigs: dict):
    """The horse's float32 rig at about `vertices` shape vertices, built once per run."""
    import jax.numpy as jnp

    import mvcjax
    from mvcjax import datasets

    if vertices not in rigs:
        rigs[vertices] = mvcjax.Rig.build(shape, datasets.horse_handles(),
                                          shape_spacing=spacing_for(shape, vertices),
                                          dtype=jnp.float32)
    return rigs[vertices]


def _poses(rig, scales):
    """`(len(scales), n, 2)` shape vertices: the demo's drag at each scale."""
    import jax
    import jax.numpy as jnp

    from mvcjax import datasets

    drag = jnp.asarray(datasets.horse_drag(), jnp.float32)
    targets = rig.handle_positions[None] + jnp.asarray(scales, jnp.float32)[:, None, None] * drag
    return jax.block_until_ready(jax.vmap(lambda t: rig.deform(t))(targets))


def _flipped(rig, poses) -> int:
    import numpy as np

    import mvcjax

    rest, faces = np.asarray(rig.shape_mesh.vertices), np.asarray(rig.shape_mesh.faces)
    return max(mvcjax.flipped_triangles(rest, np.asarray(p), faces) for p in poses)


# ---- render ----------------------------------------------------------------------------


@functools.lru_cache
def _draw_at(ref: str):
    """The renderer's drawing function (`_draw`) as it was at git commit `ref`, loaded
    beside the current one, for a before-and-after timing on the same renderer."""
    import importlib.util
    import subprocess

    import mvcjax

    source = subprocess.run(["git", "show", f"{ref}:mvcjax/rendering/_render.py"], check=True,
                            capture_output=True, text=True,
                            cwd=os.path.dirname(os.path.abspath(__file__))).stdout
    name = "mvcjax.rendering._render_at_baseline"
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(name, None))
    module.__package__ = mvcjax.rendering.__name__  # its relative imports, as the module's
    sys.modules[name] = module  # dataclasses look their module up while it runs
    exec(compile(source, f"{ref}:mvcjax/rendering/_render.py", "exec"), module.__dict__)
    return module._draw


def _against_baseline(renderer, singles, ref: str, repeats: int) -> dict:
    """The frame's median time now and at `ref`, timed in turns, and their ratio."""
    import jax
    import numpy as np

    from mvcjax.rendering._render import _draw

    before = _draw_at(ref)
    ways = {"now": jax.jit(lambda v: _draw(renderer, v, renderer.window)),
            "before": jax.jit(lambda v: before(renderer, v, renderer.window))}
    difference = float(np.abs(np.asarray(ways["now"](singles[0]))
                              - np.asarray(ways["before"](singles[0]))).max())
    times = interleaved_median_ms({k: (f, [(v,) for v in singles]) for k, f in ways.items()},
                                  repeats)
    return {"baseline_ref": ref, "baseline_single_ms": times["before"],
            "interleaved_single_ms": times["now"],
            "speedup_over_baseline": times["before"] / times["now"],
            "baseline_max_pixel_difference": difference}


def _print_against(row: dict, baseline: str) -> None:
    print(f"  against {baseline}, timed in turns: {row['interleaved_single_ms']:.2f} ms now, "
          f"{row['baseline_single_ms']:.2f} ms before, {row['speedup_over_baseline']:.2f}x "
          f"(pictures differ by at most {row['baseline_max_pixel_difference']:.1e})",
          flush=True)


def run_render(shape, vertices_list, sizes, repeats: int, quick: bool, rigs: dict,
               baseline: str | None = None) -> list[dict]:
    import jax
    import numpy as np

    import mvcjax

    rows = []
    for target in vertices_list:
        rig = _rig_of(shape, target, rigs)
        batch = max(_batch(s, quick) for s in sizes)
        poses = _poses(rig, np.linspace(0.2, 1.0, batch))
        flipped = _flipped(rig, poses)
        for size in sizes:
            count = _batch(size, quick)
            frames = poses[np.linspace(0, batch - 1, count).round().astype(int)]
            singles = [frames[i] for i in range(count)]
            window = mvcjax.fit_window(poses, (size, size))
            renderer = mvcjax.Renderer.build(rig, size=(size, size), window=window)
            hard = mvcjax.Renderer.build(rig, size=(size, size), window=window, antialias=False)
            single = jax.jit(lambda v, r=renderer: r(v))
            single_hard = jax.jit(lambda v, r=hard: r(v))
            batched = jax.jit(jax.vmap(renderer))
            # Renderer.frames' way: one frame after another inside one program (its
            # argument named as the renderer's, so that the two programs can be compared).
            mapped = jax.jit(lambda vertices, r=renderer: jax.lax.map(r, vertices))

            def loop(frames, f=single):
                return [f(v) for v in frames]

            row = {
                "kind": "render",
                "target_shape_vertices": target,
                "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                "shape_faces": int(rig.shape_mesh.faces.shape[0]),
                "size": f"{size}x{size}",
                "rows": size,
                "cols": size,
                "tile": renderer.tile,
                "budget": renderer.budget,
                "tile_no_antialias": hard.tile,
                "budget_no_antialias": hard.budget,
                "batch": count,
                "flipped_triangles": flipped,
                "compile_ms": compile_ms(single, singles[0]),
            }
            row["no_antialias_compile_ms"] = compile_ms(single_hard, singles[0])
            # In turns, over a longer window than one burst of another process's work.
            times = interleaved_median_ms({"single": (single, [(v,) for v in singles]),
                                           "hard": (single_hard, [(v,) for v in singles])},
                                          2 * repeats, budget_s=10.0)
            row["single_ms"], row["no_antialias_single_ms"] = times["single"], times["hard"]
            row["batch_compile_ms"] = compile_ms(batched, frames)
            row["map_compile_ms"] = compile_ms(mapped, frames)
            # The three ways over the same frames, timed in turns: their ratios hold
            # however busy the machine is.
            times = interleaved_median_ms({"batch": (batched, [(frames,)]),
                                           "loop": (loop, [(singles,)]),
                                           "map": (mapped, [(frames,)])},
                                          max(3, repeats // 2), budget_s=10.0, block=3)
            row["batch_ms"] = times["batch"]
            row["batch_frame_ms"] = row["batch_ms"] / count
            row["loop_ms"] = times["loop"]
            row["loop_frame_ms"] = row["loop_ms"] / count
            row["batch_over_loop_throughput"] = row["loop_ms"] / row["batch_ms"]
            row["map_ms"] = times["map"]
            row["map_frame_ms"] = row["map_ms"] / count
            row["map_over_loop_throughput"] = row["loop_ms"] / row["map_ms"]
            row["vmap_over_map_throughput"] = row["map_ms"] / row["batch_ms"]
            row["vmap_same_program_as_map"] = _same_program(batched, mapped, frames)
            if size == TARGET_SIZE and target == TARGET_VERTICES:
                row["target_frame_ms"] = TARGET_FRAME_MS
                row["frame_target_met"] = row["single_ms"] <= TARGET_FRAME_MS
                row["batch_frame_target_met"] = row["batch_frame_ms"] <= TARGET_FRAME_MS
                if baseline:
                    row.update(_against_baseline(renderer, singles, baseline, 4 * repeats))
                    _print_against(row, baseline)
            rows.append(row)
            print(_render_line(row), flush=True)
    return rows


def _same_program(first, second, *args) -> bool:
    """Whether two jitted functions compile to the same program for `args` (the
    optimised HLO, its module name and source locations aside): their times then differ only by
    the machine's noise."""
    import re

    def text(f):
        hlo = f.lower(*args).compile().as_text()
        hlo = re.sub(r"^HloModule \S+", "HloModule", hlo, flags=re.M)
        hlo = re.sub(r"(, )?metadata=\{[^}]*\}", "", hlo)
        # The stack-frame tables list the Python functions traced.
        return [line for line in hlo.splitlines()
                if not re.match(r'^\d+ ("|\{)', line)]

    return text(first) == text(second)


RENDER_HEADER = (f"{'V_S':>6} {'size':>9} {'tile':>4} {'budget':>8} {'compile':>8} "
                 f"{'frame':>8} {'no AA':>8} {'B':>3} {'batch/frame':>11} {'map/frame':>10} "
                 f"{'loop/frame':>10} {'loop/batch':>10}")


def _render_line(row) -> str:
    return (f"{row['shape_vertices']:>6} {row['size']:>9} {row['tile']:>4} {row['budget']:>8} "
            f"{row['compile_ms']:>6.0f}ms {row['single_ms']:>6.2f}ms "
            f"{row['no_antialias_single_ms']:>6.2f}ms {row['batch']:>3} "
            f"{row['batch_frame_ms']:>9.2f}ms {row['map_frame_ms']:>8.2f}ms "
            f"{row['loop_frame_ms']:>8.2f}ms "
            f"{row['batch_over_loop_throughput']:>9.2f}x")


# ---- peers -----------------------------------------------------------------------------


def _peer_ms(fn, repeats: int, once_s: float = 0.5, budget_s: float = 5.0):
    """Median ms of calls of `fn()` (no compilation to leave out), and how many calls:
    one if the first takes more than `once_s` (it is then the time), else the first is a
    warm-up and up to `repeats` more are timed, fewer past `budget_s`."""
    import numpy as np

    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    if first > once_s:
        return first * 1e3, 1, out
    times = []
    for _ in range(max(repeats, 1)):
        if len(times) >= 3 and sum(times) > budget_s:
            break
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3), len(times), out


def _texture(rest, columns: int = 512):
    """Scikit-image's astronaut, resized onto the rest window of the shape (square
    texels, a 5% margin), opaque RGBA float32, and that window."""
    import numpy as np
    from skimage import data, transform

    import mvcjax

    lo_x, lo_y, hi_x, hi_y = mvcjax.fit_window(rest)
    rows = round(columns * (hi_y - lo_y) / (hi_x - lo_x))
    window = mvcjax.fit_window(rest, (rows, columns))
    rgb = transform.resize(data.astronaut(), (rows, columns), anti_aliasing=True)
    return np.concatenate([rgb, np.ones((rows, columns, 1))], axis=-1).astype(np.float32), window


def _pixels(points, window, rows: int, cols: int):
    """Plane points to `(col, row)` pixel positions, pixel centres at whole numbers: the
    convention of mvcjax's renderer, and of scikit-image's `warp` coordinates."""
    import numpy as np

    p = np.asarray(points, np.float64)
    xmin, ymin, xmax, ymax = window
    return np.stack([(p[:, 0] - xmin) * (cols / (xmax - xmin)) - 0.5,
                     (ymax - p[:, 1]) * (rows / (ymax - ymin)) - 0.5], axis=-1)


def _interior(deformed_pixels, faces, alpha, distance: float):
    """Pixels drawn by mvcjax (alpha > 1/2) whose centre is at least `distance` pixels
    from the deformed mesh's outline."""
    import numpy as np
    import shapely

    from mvcjax.export import outline_rings

    segments = np.concatenate([np.stack([ring, np.roll(ring, -1, axis=0)], axis=1)
                               for ring in outline_rings(deformed_pixels, faces)])
    tree = shapely.STRtree(shapely.linestrings(segments))
    r, c = np.nonzero(alpha > 0.5)
    near = tree.query(shapely.points(c.astype(float), r.astype(float)), predicate="dwithin",
                      distance=distance)[0]
    inside = np.zeros(alpha.shape, bool)
    keep = np.ones(len(r), bool)
    keep[near] = False
    inside[r[keep], c[keep]] = True
    return inside


def _premultiplied(rgba):
    import numpy as np

    rgba = np.asarray(rgba, np.float64)
    return np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1)


def _agreement(ours, theirs, interior) -> dict:
    """Premultiplied RGBA differences (0..1): inside, and on the edges (the rest of what
    either drew)."""
    import numpy as np

    difference = np.abs(_premultiplied(ours) - _premultiplied(theirs)).max(axis=-1)
    drawn = (np.asarray(ours)[..., 3] > 0) | (np.asarray(theirs)[..., 3] > 0)
    edge = drawn & ~interior
    ours_drawn, theirs_drawn = np.asarray(ours)[..., 3] > 0.5, np.asarray(theirs)[..., 3] > 0.5
    return {
        "interior_pixels": int(interior.sum()),
        "interior_max_abs_diff": float(difference[interior].max()),
        "interior_mean_abs_diff": float(difference[interior].mean()),
        "interior_pixels_over_1e-3": int((difference[interior] > 1e-3).sum()),
        "edge_pixels": int(edge.sum()),
        "edge_max_abs_diff": float(difference[edge].max()) if edge.any() else 0.0,
        "edge_mean_abs_diff": float(difference[edge].mean()) if edge.any() else 0.0,
        "peer_only_pixels": int((theirs_drawn & ~ours_drawn).sum()),
        "mvcjax_only_pixels": int((ours_drawn & ~theirs_drawn).sum()),
    }


def run_peers(shape, vertices: int, sizes, repeats: int, note: str, rigs: dict) -> list[dict]:
    import numpy as np

    rig = _rig_of(shape, vertices, rigs)
    pose = _poses(rig, [PEER_DRAG])[0]
    texture, texture_window = _texture(np.asarray(rig.shape_mesh.vertices, np.float64))
    rows = []
    for size in sizes:
        rows += _compare(rig, pose, size, texture, texture_window, repeats, note)
    return rows


def _compare(rig, pose, size: int, texture, texture_window, repeats: int, note: str) -> list:
    """mvcjax and each peer at one output size: times and agreement rows."""
    import equinox as eqx
    import jax
    import matplotlib.tri as mtri
    import numpy as np
    from scipy import ndimage
    from skimage import transform

    import mvcjax

    rest = np.asarray(rig.shape_mesh.vertices, np.float64)
    faces = np.asarray(rig.shape_mesh.faces)
    deformed = np.asarray(pose, np.float64)
    t_rows, t_cols = texture.shape[:2]
    texture_points = _pixels(rest, texture_window, t_rows, t_cols)
    # A linear ramp in place of the picture: its bilinear lookup is exact, so that the
    # picture holds the texture position each pixel was given.
    ramp = np.zeros_like(texture)
    ramp[..., 0] = np.arange(t_cols)[None, :] / (t_cols - 1)
    ramp[..., 1] = np.arange(t_rows)[:, None] / (t_rows - 1)
    ramp[..., 3] = 1.0
    rows = []
    window = mvcjax.fit_window(pose, (size, size))
    renderer = mvcjax.Renderer.build(rig, texture, size=(size, size), window=window,
                                     image_window=texture_window)
    single = jax.jit(lambda v, r=renderer: r(v))
    ours_compile = compile_ms(single, pose)
    ours_ms = median_ms(single, [(pose,)], repeats)
    ours = np.asarray(single(pose))
    ramp_renderer = eqx.tree_at(lambda r: r.texture, renderer,
                                jax.numpy.asarray(ramp, renderer.texture.dtype))
    positions = np.asarray(ramp_renderer(pose), np.float64)[..., :2] * [t_cols - 1,
                                                                         t_rows - 1]
    src = _pixels(deformed, window, size, size)
    interior = _interior(src, faces, ours[..., 3], INSIDE_PIXELS)
    common = {
        "kind": "peer",
        "size": f"{size}x{size}",
        "rows": size,
        "cols": size,
        "shape_vertices": len(rest),
        "shape_faces": len(faces),
        "drag_scale": PEER_DRAG,
        "flipped_triangles": _flipped(rig, [pose]),
        "texture": f"skimage.data.astronaut() resized to {t_rows}x{t_cols}",
        "mvcjax_compile_ms": ours_compile,
        "mvcjax_ms": ours_ms,
        "inside_pixels_from_outline": INSIDE_PIXELS,
        "note": note,
    }

    # scikit-image: its estimate triangulates the points itself (Delaunay, over
    # their convex hull), forwards and backwards. `from_estimate` refuses the rest
    # points (a few flat Delaunay triangles along straight runs of the outline);
    # the deprecated `estimate` keeps the forward map, which is all `warp` needs.
    def estimate():
        tform = transform.PiecewiseAffineTransform()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tform.estimate(src, texture_points)
        return tform

    estimate_ms, estimate_runs, tform = _peer_ms(estimate, repeats)
    warp_ms, warp_runs, warped = _peer_ms(
        lambda t=tform: transform.warp(texture.astype(np.float64), t,
                                       output_shape=(size, size), order=1), repeats)
    total = estimate_ms + warp_ms
    row = {**common, "peer": "skimage PiecewiseAffineTransform + warp",
           "estimate_ms": estimate_ms, "estimate_runs": estimate_runs,
           "warp_ms": warp_ms, "warp_runs": warp_runs, "peer_ms": total,
           "peer_over_mvcjax": total / ours_ms,
           "delaunay_triangles": len(tform._tesselation.simplices),
           "failed_inverse_triangles": int(sum(bool(np.isnan(a.params).any())
                                               for a in tform.inverse_affines)),
           **_agreement(ours, warped, interior)}
    rows.append(row)
    print(_peer_line(row), flush=True)

    # matplotlib + scipy: the mesh's own triangles.
    centre_cols, centre_rows = np.meshgrid(np.arange(size, dtype=np.float64),
                                           np.arange(size, dtype=np.float64))

    def triangulate():
        tri = mtri.Triangulation(src[:, 0], src[:, 1], faces)
        return (mtri.LinearTriInterpolator(tri, texture_points[:, 0]),
                mtri.LinearTriInterpolator(tri, texture_points[:, 1]))

    try:
        triangulate_ms, _, (at_u, at_v) = _peer_ms(triangulate, repeats)
    except RuntimeError as error:  # "Triangulation is invalid": overlapping triangles
        print(f"matplotlib refused the pose: {error}")
        return rows
    interpolate_ms, _, (u, v) = _peer_ms(
        lambda: (at_u(centre_cols, centre_rows), at_v(centre_cols, centre_rows)), repeats)

    def sample(u=u, v=v):
        inside = ~np.ma.getmaskarray(u)
        at = [v.filled(0.0), u.filled(0.0)]
        out = np.stack([ndimage.map_coordinates(texture[..., k].astype(np.float64), at,
                                                order=1, mode="nearest")
                        for k in range(4)], axis=-1)
        out[..., 3] *= inside
        return out

    sample_ms, _, sampled = _peer_ms(sample, repeats)
    total = triangulate_ms + interpolate_ms + sample_ms
    exact = np.stack([u.filled(np.nan), v.filled(np.nan)], axis=-1)
    texel_error = np.abs(positions - exact).max(axis=-1)[interior]
    row = {**common, "peer": "matplotlib LinearTriInterpolator + scipy map_coordinates",
           "triangulate_ms": triangulate_ms, "interpolate_ms": interpolate_ms,
           "sample_ms": sample_ms, "peer_ms": total, "peer_over_mvcjax": total / ours_ms,
           "mvcjax_texel_error_max": float(texel_error.max()),
           "mvcjax_texel_error_mean": float(texel_error.mean()),
           **_agreement(ours, sampled, interior)}
    rows.append(row)
    print(_peer_line(row), flush=True)
    # The two peers against each other (both float64): where scikit-image's Delaunay
    # triangles differ from the mesh's.
    between = _agreement(warped, sampled, interior)
    rows[0]["vs_matplotlib_interior_max_abs_diff"] = between["interior_max_abs_diff"]
    rows[0]["vs_matplotlib_interior_mean_abs_diff"] = between["interior_mean_abs_diff"]
    rows[0]["vs_matplotlib_interior_pixels_over_1e-3"] = between["interior_pixels_over_1e-3"]
    print(f"scikit-image against matplotlib, inside: max {between['interior_max_abs_diff']:.1e}"
          f", mean {between['interior_mean_abs_diff']:.1e}, "
          f"{between['interior_pixels_over_1e-3']} px over 1e-3 (Delaunay triangles against "
          "the mesh's)", flush=True)
    return rows


def _peer_line(row) -> str:
    if "estimate_ms" in row:
        parts = (f"estimate {row['estimate_ms']:.0f} ms ({row['estimate_runs']} run"
                 f"{'s' if row['estimate_runs'] > 1 else ''}) + warp {row['warp_ms']:.0f} ms "
                 f"({row['warp_runs']} run{'s' if row['warp_runs'] > 1 else ''})")
    else:
        parts = (f"triangulate {row['triangulate_ms']:.1f} + interpolate "
                 f"{row['interpolate_ms']:.1f} + sample {row['sample_ms']:.1f} ms")
    texels = (f"; mvcjax's texture positions inside: max error {row['mvcjax_texel_error_max']:.1e}"
              f", mean {row['mvcjax_texel_error_mean']:.1e} texels"
              if "mvcjax_texel_error_max" in row else "")
    return (f"{row['peer']} | V_S={row['shape_vertices']} {row['size']}: {parts} = "
            f"{row['peer_ms']:.1f} ms, {row['peer_over_mvcjax']:.1f}x mvcjax's "
            f"{row['mvcjax_ms']:.2f} ms | inside ({row['interior_pixels']} px): max "
            f"{row['interior_max_abs_diff']:.1e}, mean {row['interior_mean_abs_diff']:.1e}; "
            f"edges ({row['edge_pixels']} px): max {row['edge_max_abs_diff']:.2f}, drawn by "
            f"the peer only {row['peer_only_pixels']} px, by mvcjax only "
            f"{row['mvcjax_only_pixels']} px{texels}")


# ---- export ----------------------------------------------------------------------------


def run_export(shape, vertices: int, count: int, repeats: int, rigs: dict) -> list[dict]:
    import jax
    import numpy as np

    import mvcjax
    from mvcjax.export import write_animation

    rig = _rig_of(shape, vertices, rigs)
    scales = 0.5 * (1.0 - np.cos(np.linspace(0.0, 2.0 * np.pi, count)))  # there and back
    poses = _poses(rig, scales)
    window = mvcjax.fit_window(poses, (EXPORT_SIZE, EXPORT_SIZE))
    renderer = mvcjax.Renderer.build(rig, size=(EXPORT_SIZE, EXPORT_SIZE), window=window)
    single = jax.jit(lambda v: renderer(v))
    compile_ms(single, poses[0])
    t0 = time.perf_counter()
    frames = np.stack(jax.device_get(jax.block_until_ready([single(p) for p in poses])))
    render_s = time.perf_counter() - t0
    print(f"{count} frames of {EXPORT_SIZE}x{EXPORT_SIZE} rendered in {render_s:.2f} s "
          f"(a loop of single frames)", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as directory:
        for suffix in FORMATS:
            path = os.path.join(directory, f"horse{suffix}")
            if suffix == ".mp4":
                try:
                    import imageio_ffmpeg  # noqa: F401
                except ImportError:
                    print("mp4: skipped (no imageio-ffmpeg: pip install 'mvcjax[video]')")
                    rows.append({"kind": "export", "format": suffix, "frames": count,
                                 "skipped": "imageio-ffmpeg not installed"})
                    continue
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                write_animation(path, frames, fps=25, progress=False)
                times.append(time.perf_counter() - t0)
            row = {
                "kind": "export",
                "format": suffix,
                "frames": count,
                "size": f"{EXPORT_SIZE}x{EXPORT_SIZE}",
                "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                "fps": 25,
                "write_s": float(np.median(times)),
                "write_runs": repeats,
                "bytes": os.path.getsize(path),
                "render_s": render_s,
            }
            rows.append(row)
            print(f"{suffix:>5}: {row['write_s']:6.2f} s, {row['bytes'] / 1e6:6.2f} MB "
                  f"({row['write_s'] / count * 1e3:.1f} ms a frame)", flush=True)
    return rows


# ---- main ------------------------------------------------------------------------------


# ---- layered characters ----------------------------------------------------------------


def _limbed_layers(parts: int):
    """A disc of a body and `parts - 1` limbs around it, each limb a layer of its own
    whose root lies over the body, with a bone from inside the body to its tip; and the
    limbs' tips turned 30 degrees about their roots, alternately either way."""
    import numpy as np
    from PIL import Image, ImageDraw

    from mvcjax import Bone, load_image

    size = LAYER_CANVAS
    centre, radius, length, width = size / 2, size * 0.18, size * 0.3, size * 0.07

    def layer(draw_on):
        image = Image.new("RGBA", (size, size), (0, 0, 0, 0))
        draw_on(ImageDraw.Draw(image))
        return load_image(image)

    def body(draw):
        draw.ellipse([centre - radius] * 2 + [centre + radius] * 2, fill=(52, 101, 164, 255))

    def flip(p):  # shape coordinates (y up) -> Pillow's (x, y down)
        return (p[0], size - 1 - p[1])

    layers, handles, pose = [layer(body)], [], []
    angles = np.linspace(0.0, 2 * np.pi, parts - 1, endpoint=False) + 0.3
    for k, angle in enumerate(angles):
        d = np.array([np.cos(angle), np.sin(angle)])
        root = centre + 0.6 * radius * d
        tip = centre + (radius + length) * d

        def limb(draw, root=root, tip=tip, k=k):
            colour = (200 - 15 * k, 120 + 10 * k, 80, 255)
            draw.line([flip(root), flip(tip)], fill=colour, width=round(2 * width))
            for p in (root, tip):
                x, y = flip(p)
                draw.ellipse([x - width, y - width, x + width, y + width], fill=colour)

        layers.append(layer(limb))
        handles.append(Bone(root, tip - 0.5 * width * d))
        turn = np.radians(30.0 if k % 2 else -30.0)
        rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        end = tip - 0.5 * width * d
        pose += [root, root + rot @ (end - root)]
    return layers, handles, np.asarray(pose)


def run_layers(part_counts, repeats: int, baseline: str | None = None) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import mvcjax

    rows = []
    for parts in part_counts:
        layers, handles, pose = _limbed_layers(parts)
        area = sum(float((layer[..., 3] > 0.5).sum()) for layer in layers)
        spacing = float(np.sqrt(area / (0.513 * LAYER_VERTICES)))  # as spacing_for
        t0 = time.perf_counter()
        character = mvcjax.Character.build(layers, handles, shape_spacing=spacing,
                                           dtype=jnp.float32)
        build_s = time.perf_counter() - t0
        size = (TARGET_SIZE, TARGET_SIZE)
        renderer = mvcjax.Renderer.build(character, layers, size=size)
        # The same figure as one silhouette: its layers flattened, bottom first.
        flat = layers[0].copy()
        for layer in layers[1:]:
            a = layer[..., 3:]
            flat[..., :3] = layer[..., :3] * a + flat[..., :3] * (1 - a)
            flat[..., 3:] = a + flat[..., 3:] * (1 - a)
        vertices_in_all = sum(p.shape_mesh.vertices.shape[0] for p in character.parts)
        silhouette = mvcjax.Shape.from_image(flat)
        rig = mvcjax.Rig.build(silhouette, handles, dtype=jnp.float32,
                               shape_spacing=spacing_for(silhouette, vertices_in_all))
        single = mvcjax.Renderer.build(rig, flat, size=size)
        targets = jnp.asarray(pose, jnp.float32)
        deform = jax.jit(mvcjax.Character.deform)
        draw = jax.jit(lambda r, v: r(v))
        one_deform = jax.jit(mvcjax.Rig.deform)
        compiles = {"deform_compile_ms": compile_ms(deform, character, targets)}
        vertices = deform(character, targets)
        compiles["render_compile_ms"] = compile_ms(draw, renderer, vertices)
        posed = one_deform(rig, targets)
        row = {
            "kind": "layers",
            "parts": parts,
            "shape_vertices": int(vertices_in_all),
            "control_vertices": int(sum(p.control_mesh.vertices.shape[0]
                                        for p in character.parts)),
            "silhouette_shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
            "size": f"{size[0]}x{size[1]}",
            "build_s": build_s,
            **compiles,
            "deform_ms": median_ms(deform, [(character, targets)], repeats),
            "render_ms": median_ms(draw, [(renderer, vertices)], repeats),
            "silhouette_deform_ms": median_ms(one_deform, [(rig, targets)], repeats),
            "silhouette_render_ms": median_ms(draw, [(single, posed)], repeats),
        }
        row["deform_over_silhouette"] = row["deform_ms"] / row["silhouette_deform_ms"]
        row["render_over_silhouette"] = row["render_ms"] / row["silhouette_render_ms"]
        rows.append(row)
        print(f"{parts:>5} {row['shape_vertices']:>6} {build_s:>7.2f}s "
              f"{row['deform_ms']:>7.2f}ms {row['silhouette_deform_ms']:>7.2f}ms "
              f"{row['render_ms']:>7.2f}ms {row['silhouette_render_ms']:>7.2f}ms", flush=True)
        if baseline:
            # A character is drawn as one mesh of all its parts (`with_order`).
            row.update(_against_baseline(renderer.with_order(None),
                                         [renderer._joined(vertices)], baseline, 4 * repeats))
            _print_against(row, baseline)
    return rows


def _targets(rows) -> dict:
    out = {"target_frame_ms_512_6k": TARGET_FRAME_MS,
           "target_vmap_over_map": TARGET_VMAP_OVER_MAP}
    for row in rows:
        if row.get("kind") == "render" and "target_frame_ms" in row:
            out["frame_ms_512_6k"] = row["single_ms"]
            out["frame_target_met"] = row["frame_target_met"]
            out["batch_frame_ms_512_6k"] = row["batch_frame_ms"]
            if "baseline_ref" in row:
                out["baseline_ref"] = row["baseline_ref"]
                out["speedup_over_baseline_512_6k"] = row["speedup_over_baseline"]
    ratios = [row["vmap_over_map_throughput"] for row in rows if row.get("kind") == "render"]
    if ratios:
        out["vmap_over_map_worst"] = min(ratios)
        out["vmap_over_map_median"] = float(sorted(ratios)[len(ratios) // 2])
        out["vmap_target_met_everywhere"] = min(ratios) >= TARGET_VMAP_OVER_MAP
        out["vmap_same_program_as_map_everywhere"] = all(
            row["vmap_same_program_as_map"] for row in rows if row.get("kind") == "render")
    return out


def _print_targets(targets) -> None:
    if "frame_ms_512_6k" in targets:
        ms = targets["frame_ms_512_6k"]
        verdict = ("met" if targets["frame_target_met"] else
                   f"missed by {ms - TARGET_FRAME_MS:.1f} ms ({ms / TARGET_FRAME_MS:.1f}x)")
        print(f"target 512x512 at 6k vertices <= {TARGET_FRAME_MS:g} ms a frame: one frame "
              f"{ms:.2f} ms, batched {targets['batch_frame_ms_512_6k']:.2f} ms a frame: "
              f"{verdict}")
    if "vmap_over_map_worst" in targets:
        verdict = "met" if targets["vmap_target_met_everywhere"] else "missed"
        print(f"target jax.vmap(renderer) >= {TARGET_VMAP_OVER_MAP:g}x the throughput of "
              f"Renderer.frames' lax.map: worst {targets['vmap_over_map_worst']:.2f}x, {verdict}")
        same = "the same" if targets["vmap_same_program_as_map_everywhere"] else "not the same"
        print(f"jax.vmap(renderer) and the lax.map compile to {same} program at every size")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="6k vertices, 256 and 512 pixels, small batches, few repeats, "
                             "peers at 256 on a 1.5k mesh, 50 exported frames")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--repeats", type=int, help="timed calls per measurement")
    parser.add_argument("--vertices", type=int, nargs="*", help="target shape-mesh vertex counts")
    parser.add_argument("--sizes", type=int, nargs="*", help="output sizes (square, pixels)")
    parser.add_argument("--peer-sizes", type=int, nargs="*",
                        help="output sizes of the peer comparison")
    parser.add_argument("--baseline", metavar="REF",
                        help="also time the target frame and the layered pictures against "
                             "the renderer at this git commit, in turns")
    parser.add_argument("--parts", nargs="*", choices=["render", "peer", "layers", "export"],
                        default=["render", "peer", "layers", "export"], help="what to run")
    args = parser.parse_args(argv)
    vertices = args.vertices or (QUICK_VERTICES if args.quick else VERTICES)
    sizes = args.sizes or (QUICK_SIZES if args.quick else SIZES)
    repeats = args.repeats or (5 if args.quick else 30)

    from mvcjax import datasets

    start = time.perf_counter()
    shape = datasets.horse()
    rows, rigs, seconds = [], {}, {}
    if "render" in args.parts:
        print(f"render, float32, checkerboard fill; frame = one jitted frame, no AA = "
              f"antialias=False, batch = jit(vmap) of B frames, map = jit(lax.map) of them "
              f"(Renderer.frames), loop = the jitted frame over the same B\n{RENDER_HEADER}",
              flush=True)
        t0 = time.perf_counter()
        rows += run_render(shape, vertices, sizes, repeats, args.quick, rigs, args.baseline)
        seconds["render_part_s"] = time.perf_counter() - t0
    if "peer" in args.parts:
        peer_vertices = QUICK_PEER_VERTICES if args.quick else TARGET_VERTICES
        note = (f"quick mode: peers on a {peer_vertices}-vertex mesh (scikit-image's estimate "
                "and warp are slow on 6k)" if args.quick else "")
        print(f"\npeers, drag x{PEER_DRAG}, the astronaut painted on the rest horse; agreement "
              f"in premultiplied RGBA (0..1), >= {INSIDE_PIXELS:g} px inside the outline"
              + (f"\n{note}" if note else ""), flush=True)
        peer_sizes = args.peer_sizes or (QUICK_PEER_SIZES if args.quick else PEER_SIZES)
        t0 = time.perf_counter()
        rows += run_peers(shape, peer_vertices, peer_sizes, repeats, note, rigs)
        seconds["peer_part_s"] = time.perf_counter() - t0
    if "layers" in args.parts:
        print(f"\nlayered characters, {TARGET_SIZE}x{TARGET_SIZE}, about {LAYER_VERTICES} shape "
              "vertices in all; one jitted frame, and the same figure as one silhouette\n"
              f"{'parts':>5} {'V_S':>6} {'build':>8} {'deform':>9} {'(one)':>9} "
              f"{'render':>9} {'(one)':>9}", flush=True)
        t0 = time.perf_counter()
        rows += run_layers(QUICK_LAYER_PARTS if args.quick else LAYER_PARTS, repeats,
                           args.baseline)
        seconds["layers_part_s"] = time.perf_counter() - t0
    if "export" in args.parts:
        count = QUICK_EXPORT_FRAMES if args.quick else EXPORT_FRAMES
        print(f"\nexport: {count} frames, {EXPORT_SIZE}x{EXPORT_SIZE}, checkerboard fill, "
              f"write_animation(fps=25)", flush=True)
        t0 = time.perf_counter()
        rows += run_export(shape, TARGET_VERTICES, count, 1 if args.quick else 3, rigs)
        seconds["export_part_s"] = time.perf_counter() - t0
    targets = _targets(rows)
    print()
    _print_targets(targets)
    seconds["total_s"] = time.perf_counter() - start
    print("seconds: " + ", ".join(f"{k[:-2]} {v:.0f}" for k, v in seconds.items()))
    if args.json:
        write_results(args.json, rows, benchmark="render", repeats=repeats, quick=args.quick,
                      **targets, **seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
