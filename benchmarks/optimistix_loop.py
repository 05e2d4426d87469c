"""mvcjax's Gauss-Newton loop against optimistix's own, with the same descent and search.

`GaussNewton`, `LevenbergMarquardt` and `Dogleg` run their steps through
`_StructuredGaussNewton`, a loop written on optimistix's public
`AbstractLeastSquaresSolver` interface that linearises the residuals in closed form and
carries the point's data only. Optimistix's `AbstractGaussNewton` runs the same descent,
search and Cauchy test with a `jax.linearize` of the residual function at every step.
Both solve the same problems to the same iterates (`tests/test_descents.py` checks it);
this measures what the loop of mvcjax's own is worth: the time of a whole solve, compiled
once outside the timed region, median of many calls timed in turns, and the compile time,
on the horse (the solve runs on its control mesh) and the character with bones, in
float32 (what users run) and float64.

    python benchmarks/optimistix_loop.py [--quick] \
        [--json benchmarks/results/optimistix_loop-cpu-2core.json]
"""

from __future__ import annotations

import sys
import time

from _timing import compile_ms, interleaved_median_ms, quick_and_json, write_results


def problems():
    from mvcjax import datasets

    return {
        "horse": (datasets.horse(), datasets.horse_handles(), datasets.horse_drag()),
        "character-arms": (datasets.character(), datasets.character_bones("arms"), None),
    }


def measure(quick: bool) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optimistix as optx

    import mvcjax
    from mvcjax import datasets
    from mvcjax._solvers._least_squares import ScaledProblem
    from mvcjax._solvers._optimistix import _GaussNewtonFamily

    solvers = {"GaussNewton": mvcjax.GaussNewton(), "LevenbergMarquardt":
               mvcjax.LevenbergMarquardt(), "Dogleg": mvcjax.Dogleg()}
    dtypes = [jnp.float32] + ([] if quick else [jnp.float64])
    rows = []
    for dtype in dtypes:
        with jax.enable_x64(dtype == jnp.float64):
            for model, (shape, handles, drag) in problems().items():
                rig = mvcjax.Rig.build(shape, handles, dtype=dtype)
                rest = np.asarray(rig.handle_positions, np.float64)
                if drag is None:  # the right arm's bone turned 60 degrees at the shoulder
                    drag = np.zeros_like(rest)
                    drag[5] = datasets._rotate(rest[5], rest[4], 60.0) - rest[5]
                frames = [rest + s * drag for s in (0.6, 0.8, 1.0)]
                for name, solver in solvers.items():
                    fns, compile_times, steps = {}, {}, {}
                    for loop in ("mvcjax", "optimistix"):
                        fn = jax.jit(_solve_with(rig, solver, loop, ScaledProblem,
                                                 _GaussNewtonFamily, optx))
                        args = [(jnp.asarray(f, dtype),) for f in frames]
                        compile_times[loop] = compile_ms(fn, *args[0])
                        steps[loop] = int(fn(*args[0])[1])
                        fns[loop] = (fn, args)
                    times = interleaved_median_ms(fns, repeats=20 if quick else 60,
                                                  budget_s=10.0 if quick else 30.0)
                    rows.append({
                        "model": model, "dtype": jnp.dtype(dtype).name, "solver": name,
                        "control_vertices": int(rig.control_mesh.vertices.shape[0]),
                        "steps": steps, "solve_ms": times, "compile_ms": compile_times,
                        "optimistix_over_mvcjax": times["optimistix"] / times["mvcjax"],
                    })
                    print(rows[-1], flush=True)
    return rows


def _solve_with(rig, solver, loop, ScaledProblem, GaussNewtonFamily, optx):
    """A function of the targets: the solve's control vertices and its step count, by
    mvcjax's loop or by optimistix's `AbstractGaussNewton` with the same parts."""

    def solve(targets):
        local = rig._pinned(targets)
        start = rig.frame.to_local(rig.start(targets))
        problem = ScaledProblem(rig.energy, local)
        y0 = problem.scaled(start)
        configured = solver._configured(problem, rig.factor, y0.dtype)
        if loop == "optimistix":
            configured = GaussNewtonFamily(rtol=configured.rtol, atol=configured.atol,
                                           descent=configured.descent,
                                           search=configured.search)
        sol = optx.least_squares(lambda y, args: problem.residuals(y), configured, y0,
                                 max_steps=solver.max_steps, throw=False)
        return sol.value, sol.stats["num_steps"]

    return solve


def format_table(data: dict) -> str:
    lines = ["| model | float | solver | steps | mvcjax's loop | optimistix's loop | ratio "
             "| compile, mvcjax / optimistix |", "|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(
            f"| {r['model']} | {r['dtype']} | {r['solver']} | {r['steps']['mvcjax']} | "
            f"{r['solve_ms']['mvcjax']:.2f} ms | {r['solve_ms']['optimistix']:.2f} ms | "
            f"{r['optimistix_over_mvcjax']:.2f}x | {r['compile_ms']['mvcjax'] / 1e3:.1f} s / "
            f"{r['compile_ms']['optimistix'] / 1e3:.1f} s |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "float32 only, fewer repeats", argv)
    start = time.perf_counter()
    rows = measure(args.quick)
    if args.json:
        write_results(args.json, rows, benchmark="optimistix_loop", quick=args.quick,
                      seconds=time.perf_counter() - start)
    print(format_table({"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
