"""Per-frame cost of the paper's pipeline on the horse, at several shape-mesh sizes.

For each size: mesh sizes, preprocessing time (Rig.build, including the compilation of
G), compile time of a frame, and the median per-frame time of solve and skin apart and
together, for the paper's method (its energy, `Weights.paper()`, and FixedG's 15
iterations), the default of `rig.deform` (its energy and solver) and GaussNewton on the
default energy (to tolerance), each from the default start. The
frame is jitted with the rig closed over (the interactive use: one rig, many targets)
and, for the combined frame, also with the rig as an argument. Compilation happens
once, outside the timed region; every timed call blocks until ready; each time is the
median over many calls with targets that change from call to call.

    python benchmarks/deform.py                 # float32 and float64, all sizes
    python benchmarks/deform.py --quick         # small sizes, few repeats (CI)
    python benchmarks/deform.py --json out.json

float64 runs in a subprocess, since jax_enable_x64 must be set before JAX starts.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

from _timing import compile_ms, median_ms, spacing_for, write_results

SIZES = [1500, 6000, 20000, 100000]
QUICK_SIZES = [1500, 6000]


def run(sizes, repeats: int, dtype_name: str) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    dtype = jnp.dtype(dtype_name)
    shape = datasets.horse()
    handles = datasets.horse_handles()
    rows = []
    for target in sizes:
        t0 = time.perf_counter()
        rig = mvcjax.Rig.build(shape, handles, shape_spacing=spacing_for(shape, target),
                               dtype=dtype)
        jax.block_until_ready(rig)
        preprocess = time.perf_counter() - t0
        rest = rig.handle_positions
        frames = [rest + s * jnp.asarray(datasets.horse_drag(), dtype)
                  for s in np.linspace(0.2, 1.0, 16)]
        row = {
            "dtype": dtype_name,
            "target_shape_vertices": target,
            "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
            "shape_faces": int(rig.shape_mesh.faces.shape[0]),
            "control_vertices": int(rig.control_mesh.vertices.shape[0]),
            "control_polygon": int(rig.control_mesh.outer.shape[0]),
            "preprocess_s": preprocess,
        }
        paper = rig.with_weights(mvcjax.Weights.paper())
        solvers = [("fixed_g15", mvcjax.FixedG(), paper),
                   ("default", mvcjax.solvers.DEFAULT_SOLVER, rig),
                   ("gauss_newton", mvcjax.GaussNewton(), rig)]
        for name, solver, rig in solvers:
            solve = jax.jit(lambda t, s=solver, r=rig: r.solve(t, s))
            skin = jax.jit(lambda v, r=rig: r.skin(v))
            frame = jax.jit(lambda t, s=solver, r=rig: r.deform(t, s))
            frame_arg = jax.jit(lambda r, t, s=solver: r.deform(t, s))
            row[f"{name}_compile_ms"] = compile_ms(frame, frames[0])
            control = [solve(t) for t in frames]
            row[f"{name}_solve_ms"] = median_ms(solve, [(t,) for t in frames], repeats)
            row[f"{name}_skin_ms"] = median_ms(skin, [(v,) for v in control], repeats)
            row[f"{name}_frame_ms"] = median_ms(frame, [(t,) for t in frames], repeats)
            row[f"{name}_frame_rig_argument_ms"] = median_ms(
                frame_arg, [(rig, t) for t in frames], repeats)
            if name == "gauss_newton":
                _, info = jax.jit(lambda t, s=solver, r=rig: r.solve(t, s, return_info=True))(
                    frames[-1])
                row["gauss_newton_steps"] = int(info.iterations)
                row["gauss_newton_converged"] = bool(info.converged)
        rows.append(row)
        print(_format(row), flush=True)
    return rows


def _format(row) -> str:
    return (
        f"{row['dtype']:>7} V_S={row['shape_vertices']:>6} V_C={row['control_vertices']:>4} "
        f"prep={row['preprocess_s']:6.2f}s | FixedG15 compile={row['fixed_g15_compile_ms']:6.0f}ms "
        f"solve={row['fixed_g15_solve_ms']:.3f} skin={row['fixed_g15_skin_ms']:.3f} "
        f"frame={row['fixed_g15_frame_ms']:.3f} "
        f"(rig as arg {row['fixed_g15_frame_rig_argument_ms']:.3f}) ms"
        f" | default frame={row['default_frame_ms']:.3f} ms"
        f" | GN solve={row['gauss_newton_solve_ms']:.2f} "
        f"frame={row['gauss_newton_frame_ms']:.2f} ms "
        f"({row['gauss_newton_steps']} steps)"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, few repeats")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--sizes", type=int, nargs="*", help="target shape-mesh vertex counts")
    parser.add_argument("--repeats", type=int, help="timed calls per measurement")
    parser.add_argument("--dtype", choices=["float32", "float64", "both"], default="both")
    parser.add_argument("--_child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    sizes = args.sizes or (QUICK_SIZES if args.quick else SIZES)
    repeats = args.repeats or (20 if args.quick else 200)

    if args._child:  # float64 worker: print rows as JSON on the last line
        import jax

        jax.config.update("jax_enable_x64", True)
        print(json.dumps(run(sizes, repeats, "float64")))
        return 0

    import jax

    rows = []
    if args.dtype in ("float32", "both"):
        rows += run(sizes, repeats, "float32")
    if args.dtype in ("float64", "both"):
        cmd = [sys.executable, __file__, "--_child", "--repeats", str(repeats), "--sizes",
               *map(str, sizes)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True)
        lines = out.stdout.strip().splitlines()
        child_rows = json.loads(lines[-1])
        for row in child_rows:
            print(_format(row))
        rows += child_rows
    if args.json:
        write_results(args.json, rows, benchmark="deform", repeats=repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
