"""The natural JAX paths on the horse: one compiled frame against this machine's memory
floor, and batches of frames through `jax.vmap` and `mvcjax.deform_frames` against a loop
and against what any batch must cost.

Four parts, float32, the default solver (`rig.deform`'s: FixedG with a fixed number of
iterations), in one run:

- bandwidth: the machine's streaming bandwidth, measured here as the median time of a
  jitted `x * 2` over a 256 MiB array, in place (read once, written once), and of
  numpy's `np.copyto` of the same array; the larger is the floor's bandwidth.
- frame: for each shape mesh (about 6k, 20k, 64k and 100k vertices) and skinning
  ("blended", the default, and the paper's "mvc"), the median time of a compiled frame,
  `jax.jit(rig.deform)` (the rig's arrays constants of the program), of the frame with
  the rig as an argument, and of the skinning alone, both skinnings timed in turns. The
  frame's memory floor is the bytes it must stream (the skinning's arrays and the
  solver's `G` read once, the vertices it writes) over the measured bandwidth; the
  fraction of the floor reached is floor / time.
- batch: at about 6k and 20k vertices, B frames (1024 by default) through
  `jax.jit(jax.vmap(rig.deform))`, `jax.jit(jax.vmap(rig.solve))`,
  `jax.jit(jax.vmap(rig.skin))` and `mvcjax.deform_frames` (also with `out=`, the
  previous result's memory reused), each against a Python loop of the jitted single
  frame (`jax.jit(rig.deform)` and so on) over the same B frames (dispatched
  asynchronously, blocked once at the end): the loop's time over the batch's.
- floors: in the same turns as the batches, a new `(B, n, 2)` result written once, the
  same written into donated memory, and the solve's global steps alone (as many as the
  default solver takes); from them,
  the best batch / loop ratio any implementation could reach with a new result and
  with reused memory (`ceiling_*`).

Batches and floors are measured twice: with glibc's default malloc, which maps a
batch's large result afresh on every call and pays the page faults again, and keeping
freed memory for reuse (`GLIBC_TUNABLES=<_timing.KEEP_FREED_TUNABLES>`, in a second
process).

Compilation happens once, outside the timed region (reported apart); every timed call
blocks until ready; times are medians of calls made in turns, so that the machine's
load weighs on both sides of a ratio alike. The targets are printed and
recorded with whether they were met, never asserted.

    python benchmarks/throughput.py                       # 6k, 20k, 64k, 100k; 1024 frames
    python benchmarks/throughput.py --quick --json FILE   # 1.5k, 6k; 64 frames
"""

from __future__ import annotations

import argparse
import sys
import time

from _timing import (
    allocator_rows,
    compile_ms,
    interleaved_median_ms,
    median_ms,
    spacing_for,
    write_results,
)

SIZES = [6000, 20000, 64000, 100000]
QUICK_SIZES = [1500, 6000]
BATCH_SIZES = [6000, 20000]
QUICK_BATCH_SIZES = [1500]
FRAMES, QUICK_FRAMES = 1024, 64
SKINNINGS = ["blended", "mvc"]
BANDWIDTH_BYTES = 256 * 2**20

TARGET_FRAME_MS = {6000: 0.25, 100000: 1.0}  # blended skinning, per frame
# vmap(rig.deform) and deform_frames against the ceiling of a new result, and
# deform_frames(out=) against the ceiling of a reused one, measured in the same run.
TARGET_SHARE_OF_CEILING = 0.8
TARGET_BLENDED_OVER_MVC = 1.5


def bandwidth_gb_s(repeats: int) -> dict:
    """Streaming bandwidth: bytes read plus bytes written per second, in place (a fresh
    256 MiB output would time the kernel's page faults instead)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    double = jax.jit(lambda a: a * 2.0, donate_argnums=0)
    state = [jnp.ones(BANDWIDTH_BYTES // 4, jnp.float32)]

    def step():
        state[0] = double(state[0])
        return state[0]

    jax_ms = median_ms(step, [()], repeats)
    a = np.ones(BANDWIDTH_BYTES // 4, np.float32)
    b = np.empty_like(a)
    numpy_ms = median_ms(lambda: np.copyto(b, a), [()], repeats)
    moved = 2 * BANDWIDTH_BYTES / 1e9
    return {"jax_scale_gb_s": moved / jax_ms * 1e3, "numpy_copy_gb_s": moved / numpy_ms * 1e3}


def _rig(shape, handles, target: int, skinning: str):
    import mvcjax

    method = {"blended": mvcjax.advanced.BlendedMVCSkinning(),
              "mvc": mvcjax.advanced.MVCSkinning()}[skinning]
    return mvcjax.Rig.build(shape, handles, shape_spacing=spacing_for(shape, target),
                            skinning=method)


def _targets(rig, count: int, seed: int = 0):
    import jax.numpy as jnp
    import numpy as np

    from mvcjax import datasets

    rest = np.asarray(rig.handle_positions)
    drag = np.asarray(datasets.horse_drag())
    s = np.random.default_rng(seed).uniform(0.2, 1.0, size=(count, 1, 1))
    return jnp.asarray(rest + s * drag, rig.handle_positions.dtype)


def _stream_bytes(rig) -> int:
    """Bytes a frame must move at least: the skinning's packed rows and `G` read once
    (the iterations find `G` in cache), the shape vertices written. (The skinning's
    blocks serve batches of frames only.)"""
    s = rig.skinning
    skin = s.tile_indices.nbytes + s.tile_weights.nbytes + s.slots.nbytes
    written = rig.shape_mesh.vertices.nbytes
    g = getattr(rig.factor, "shape", None)  # a dense factor's G (its shape part)
    return int(skin + written + (g.nbytes if g is not None else 0))


def run_frames(shape, handles, sizes, repeats: int, bandwidth: float) -> list[dict]:
    import jax

    rows = []
    for target in sizes:
        timed, size_rows = {}, {}
        for skinning in SKINNINGS:
            rig = _rig(shape, handles, target, skinning)
            targets = _targets(rig, 16)
            frame = jax.jit(rig.deform)  # the documented fastest: the rig's arrays constants
            argument = jax.jit(lambda r, t: r.deform(t))
            skin_fn, solve = jax.jit(rig.skin), jax.jit(rig.solve)
            control = [solve(t) for t in targets]
            size_rows[skinning] = {
                "target_shape_vertices": target,
                "skinning": skinning,
                "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                "control_vertices": int(rig.control_mesh.vertices.shape[0]),
                "skin_row_width": int(rig.skinning.indices.shape[-1]),
                "compile_ms": compile_ms(frame, targets[0]),
                "rig_argument_compile_ms": compile_ms(argument, rig, targets[0]),
                "stream_bytes": _stream_bytes(rig),
            }
            timed[(skinning, "frame_ms")] = (frame, [(t,) for t in targets])
            timed[(skinning, "frame_rig_argument_ms")] = (argument, [(rig, t) for t in targets])
            timed[(skinning, "skin_ms")] = (skin_fn, [(v,) for v in control])
        # Both skinnings in turns: their ratio comes from one run, whatever else the
        # machine is doing.
        for (skinning, key), ms in interleaved_median_ms(timed, repeats).items():
            size_rows[skinning][key] = ms
        for skinning, row in size_rows.items():
            row["floor_ms"] = row["stream_bytes"] / bandwidth * 1e3
            row["fraction_of_floor"] = row["floor_ms"] / row["frame_ms"]
            goal = TARGET_FRAME_MS.get(target)
            if goal is not None and skinning == "blended":
                row["target_frame_ms"] = goal
                row["target_met"] = row["frame_ms"] <= goal
            rows.append(row)
            print(f"V_S={row['shape_vertices']:>6} {skinning:>8} (width "
                  f"{row['skin_row_width']}): frame {row['frame_ms']:.3f} ms "
                  f"(rig as argument {row['frame_rig_argument_ms']:.3f} ms), skin "
                  f"{row['skin_ms']:.3f} ms, floor {row['floor_ms']:.3f} ms "
                  f"({row['fraction_of_floor']:.0%}), compile {row['compile_ms']:.0f} ms "
                  f"(rig as argument {row['rig_argument_compile_ms']:.0f} ms)", flush=True)
        blended, mvc = size_rows["blended"], size_rows["mvc"]
        blended["blended_over_mvc"] = blended["frame_ms"] / mvc["frame_ms"]
        print(f"V_S={blended['shape_vertices']:>6}: blended / mvc per frame "
              f"{blended['blended_over_mvc']:.2f}x (target <= {TARGET_BLENDED_OVER_MVC})")
    return rows


def _batch_paths(rig, batches, singles):
    """Each batched path with the single frame whose loop it is measured against (a key
    of `singles`, the jitted single frames), and its inputs: the natural spellings."""
    import jax

    import mvcjax

    controls = [jax.vmap(singles["solve"])(b) for b in batches]
    held = [mvcjax.deform_frames(rig, batches[0])]

    def into(b):  # each call reusing the previous result's memory
        held[0] = mvcjax.deform_frames(rig, b, out=held[0])
        return held[0]

    return {
        "vmap_deform": (jax.jit(jax.vmap(rig.deform)), "deform", batches),
        "deform_frames": (lambda b: mvcjax.deform_frames(rig, b), "deform", batches),
        "deform_frames_out": (into, "deform", batches),
        "vmap_solve": (jax.jit(jax.vmap(rig.solve)), "solve", batches),
        "vmap_skin": (jax.jit(jax.vmap(rig.skin)), "skin", controls),
    }


def _floors(rig, batches):
    """What any batch of these frames costs at least, as programs to time.

    - `result_fresh`: a new `(frames, n, 2)` result written once: the kernel's page
      faults and zeroing of fresh memory, which a batch returning a new array pays
      whatever it computes (a loop of single frames reuses its small blocks).
    - `result_reused`: the same written into donated memory (`deform_frames(out=)`).
    - `solve_products`: the fixed-G iteration's global steps alone, `N^{-1}` times the
      frames' right-hand sides (`c x 2f`), once per iteration: the method's own least
      work per batch (the paper's `G` would be 2.3 times as many flops).
    """
    import jax
    import jax.numpy as jnp
    import numpy as np


    frames = batches[0].shape[0]
    n = rig.shape_mesh.vertices.shape[0]
    dtype = rig.energy.rest.dtype
    fresh = jax.jit(lambda t: jnp.broadcast_to(t[:, :1, :1], (frames, n, 2)))
    held = [jnp.zeros((frames, n, 2), dtype)]
    # An update of the donated array in place (a bare broadcast would get new memory).
    write = jax.jit(lambda out, t: jax.lax.dynamic_update_slice(
        out, jnp.broadcast_to(t[:, :1, :1], out.shape), (0, 0, 0)), donate_argnums=0)

    def reused(t):
        held[0] = write(held[0], t)
        return held[0]

    from mvcjax.solvers import DEFAULT_SOLVER

    floors = {"result_fresh": (fresh, batches), "result_reused": (reused, batches)}
    inverse = getattr(rig.factor, "normal_inverse", None)
    if inverse is not None:  # a dense factor (every control mesh of the horse)
        # As many products as the solves timed beside it take.
        iterations = DEFAULT_SOLVER.iterations
        rhs = [jnp.asarray(np.random.default_rng(k).normal(size=(inverse.shape[0], 2 * frames)),
                           dtype) for k in range(2)]
        products = jax.jit(lambda x: jax.lax.fori_loop(0, iterations, lambda _, v: inverse @ v, x))
        floors["solve_products"] = (products, rhs)
    return floors


def run_batches(shape, handles, sizes, count: int, repeats: int, allocator: str) -> list[dict]:
    import jax

    rows = []
    for target in sizes:
        rig = _rig(shape, handles, target, "blended")
        batches = [_targets(rig, count, seed) for seed in range(2)]
        row = {"target_shape_vertices": target, "frames": count, "allocator": allocator,
               "shape_vertices": int(rig.shape_mesh.vertices.shape[0])}
        singles = {"deform": jax.jit(rig.deform), "solve": jax.jit(rig.solve),
                   "skin": jax.jit(rig.skin)}
        paths = _batch_paths(rig, batches, singles)
        timed = {}
        for name, (batched, single, inputs) in paths.items():
            row[f"{name}_compile_ms"] = compile_ms(batched, inputs[0])
            timed[name] = (batched, [(b,) for b in inputs])
            if f"{single}_loop" not in timed:
                def loop(b, single=singles[single]):
                    return [single(x) for x in b]

                timed[f"{single}_loop"] = (loop, [(b,) for b in inputs])
        for name, (fn, inputs) in _floors(rig, batches).items():
            timed[f"floor_{name}"] = (fn, [(b,) for b in inputs])
        # In turns, so that whatever else the machine does weighs on a batch and its loop
        # alike: every ratio comes from one run.
        times = interleaved_median_ms(timed, repeats, budget_s=30.0, block=2)
        for name, (_, single, _) in paths.items():
            row[f"{name}_ms"] = times[name]
            row[f"{name}_loop_ms"] = times[f"{single}_loop"]
            row[f"{name}_speedup"] = row[f"{name}_loop_ms"] / row[f"{name}_ms"]
            print(f"V_S={row['shape_vertices']:>6} {count} frames {name:>17} ({allocator}): batch "
                  f"{row[f'{name}_ms']:8.1f} ms ({count / row[f'{name}_ms'] * 1e3:8.0f} "
                  f"frames/s), loop {row[f'{name}_loop_ms']:8.1f} ms, batch/loop "
                  f"{row[f'{name}_speedup']:5.1f}x", flush=True)
        for name in ("result_fresh", "result_reused", "solve_products"):
            if f"floor_{name}" in times:
                row[f"floor_{name}_ms"] = times[f"floor_{name}"]
        if "floor_solve_products_ms" in row:
            # The best ratio any implementation of this method could reach, were the
            # local steps and the skinning free.
            loop_ms = row["vmap_deform_loop_ms"]
            solve = row["floor_solve_products_ms"]
            row["ceiling_fresh_speedup"] = loop_ms / (row["floor_result_fresh_ms"] + solve)
            row["ceiling_reused_speedup"] = loop_ms / (row["floor_result_reused_ms"] + solve)
            print(f"V_S={row['shape_vertices']:>6} {count} frames floors ({allocator}): fresh "
                  f"result {row['floor_result_fresh_ms']:.1f} ms, reused "
                  f"{row['floor_result_reused_ms']:.1f} ms, the solve's products {solve:.1f} ms: "
                  f"at best {row['ceiling_fresh_speedup']:.1f}x the loop with a new result "
                  f"(vmap, deform_frames), {row['ceiling_reused_speedup']:.1f}x with out=",
                  flush=True)
        if "ceiling_fresh_speedup" in row:
            row["share_of_ceiling"] = (min(row["vmap_deform_speedup"],
                                           row["deform_frames_speedup"])
                                       / row["ceiling_fresh_speedup"])
            row["out_share_of_ceiling"] = (row["deform_frames_out_speedup"]
                                           / row["ceiling_reused_speedup"])
            row["target_share_of_ceiling"] = TARGET_SHARE_OF_CEILING
            row["target_met"] = min(row["share_of_ceiling"],
                                    row["out_share_of_ceiling"]) >= TARGET_SHARE_OF_CEILING
            print(f"V_S={row['shape_vertices']:>6} ({allocator}): vmap and deform_frames at "
                  f"{row['share_of_ceiling']:.0%} of the ceiling, out= at "
                  f"{row['out_share_of_ceiling']:.0%} (target {TARGET_SHARE_OF_CEILING:.0%}: "
                  f"{'met' if row['target_met'] else 'missed'})", flush=True)
        rows.append(row)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small meshes and batches (CI)")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--sizes", type=int, nargs="*", help="shape-mesh sizes of the frame part")
    parser.add_argument("--batch-sizes", type=int, nargs="*",
                        help="shape-mesh sizes of the batch part")
    parser.add_argument("--frames", type=int, help="frames in a batch")
    parser.add_argument("--repeats", type=int, help="timed calls per measurement")
    parser.add_argument("--allocator", choices=["default", "keep_freed", "both"], default="both",
                        help="batches with glibc's default malloc, with one keeping freed "
                             "memory (_timing.KEEP_FREED_TUNABLES), or both")
    args = parser.parse_args(argv)
    from mvcjax import datasets

    sizes = args.sizes if args.sizes is not None else (QUICK_SIZES if args.quick else SIZES)
    batch_sizes = (args.batch_sizes if args.batch_sizes is not None
                   else QUICK_BATCH_SIZES if args.quick else BATCH_SIZES)
    count = args.frames or (QUICK_FRAMES if args.quick else FRAMES)
    repeats = args.repeats or (10 if args.quick else 100)
    t0 = time.perf_counter()
    bandwidth = bandwidth_gb_s(max(5, repeats // 10))
    best = max(bandwidth.values())
    print(f"bandwidth: jax {bandwidth['jax_scale_gb_s']:.1f} GB/s, numpy copy "
          f"{bandwidth['numpy_copy_gb_s']:.1f} GB/s", flush=True)
    shape, handles = datasets.horse(), datasets.horse_handles()
    rows = [{"part": "bandwidth", **bandwidth}]
    rows += [{"part": "frame", **r}
             for r in run_frames(shape, handles, sizes, repeats, best * 1e9)]
    rows += allocator_rows(
        args.allocator,
        lambda allocator: [{"part": "batch", **r} for r in run_batches(
            shape, handles, batch_sizes, count, max(5, repeats // 10), allocator)],
        __file__, sys.argv[1:] if argv is None else argv, child_args=("--sizes",))
    print(f"total {time.perf_counter() - t0:.0f} s")
    if args.json:
        write_results(args.json, rows, benchmark="throughput", repeats=repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
