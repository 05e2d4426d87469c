"""Every solver on the energy (6): energy against iteration and against time, iterations
and time to a relative energy gap of 1e-6 to the lowest minimum found, compile time.

For each model (the horse, and the paper-like character, flower and stick) and its
default drag, in float64 (a relative gap of 1e-6 is below what float32 resolves):

- the energy after every step of every solver (`Rig.energy_history`, stopping criteria
  off), and the lowest energy any of them reached: the reference minimum;
- steps to a relative gap of 1e-6 to it (none if a solver settles in another stationary
  point or runs out of steps);
- the time to the gap: a solve of exactly that many steps (tolerances off), compiled
  once outside the timed region, median of many calls (never extrapolated); every
  solver's solves timed in turns, so that ratios come from one run;
- the time of one step, two ways: that time divided by the steps (what a solve costs
  per step, its fixed costs included), and the marginal cost, the difference to a solve
  of half as many steps divided by the steps between (what one more step costs);
- compile time: the first call of that solve.

The targets: one step of the optimistix solvers costs at most 10 plain fixed-G steps;
the best of them reaches the gap in less time than plain fixed-G; Anderson-accelerated
fixed-G needs at most a tenth of plain fixed-G's steps. The script prints them.

    python benchmarks/solvers.py                        # all four models
    python benchmarks/solvers.py --quick --json FILE    # the horse, fewer repeats
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from _timing import compile_ms, interleaved_median_ms, write_results

GAP = 1e-6


def solvers():
    """name -> (solver, steps to record)."""
    import lineax as lx

    import mvcjax

    return {
        # unroll=0: timed solves of a few steps run the same loop as long ones.
        "fixed_g": (mvcjax.FixedG(unroll=0), 6000),
        "anderson": (mvcjax.FixedG(anderson=5, unroll=0), 800),
        "gauss_newton": (mvcjax.GaussNewton(), 400),
        "dogleg": (mvcjax.Dogleg(), 400),
        "levenberg_marquardt": (mvcjax.LevenbergMarquardt(), 400),
        # The earlier default, for comparison in the same run: 8 plain CG iterations a step.
        "gauss_newton_cg8_undeflated": (mvcjax.GaussNewton(
            linear_solver=mvcjax.advanced.StructuredCG(steps=8, deflate=False)), 400),
        "gauss_newton_cholesky": (mvcjax.GaussNewton(linear_solver=lx.Cholesky()), 200),
        "jaxopt_gauss_newton": (mvcjax.advanced.JaxoptGaussNewton(), 200),
        "jaxopt_levenberg_marquardt": (mvcjax.advanced.JaxoptLevenbergMarquardt(), 200),
    }


def sampled_steps(count: int):
    """Up to about 350 of the steps `0..count-1`: every one of the first 50, then spaced
    evenly on a log scale (what the plot shows), and the last."""
    import numpy as np

    steps = np.concatenate([np.arange(min(count, 50)),
                            np.geomspace(1, count - 1, 300).astype(int), [count - 1]])
    return np.unique(steps)


def steps_to_gap(energies, minimum):
    import numpy as np

    reached = np.flatnonzero((energies - minimum) / minimum <= GAP)
    return int(reached[0]) if reached.size else None


def run_model(name: str, repeats: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from mvcjax import Weights, datasets

    model = datasets.model(name)
    rig = model.rig(dtype=jnp.float64, weights=Weights.paper())  # the paper's energy
    targets = rig.handle_positions + jnp.asarray(model.drag)
    histories, compile_times = {}, {}
    for solver_name, (solver, steps) in solvers().items():
        history = jax.jit(lambda t, s=solver, n=steps: rig.energy_history(t, s, n))
        histories[solver_name] = np.asarray(history(targets))
        print(f"  {name} {solver_name}: {steps} steps recorded", file=sys.stderr)
    minimum = min(float(h.min()) for h in histories.values())

    timed, counts = {}, {}
    for solver_name, (solver, steps) in solvers().items():
        reached = steps_to_gap(histories[solver_name], minimum)
        # Time the solve up to the gap, or over all recorded steps if it never got there.
        counts[solver_name] = max(steps if reached is None else reached, 2)
        fixed = solver.fixed_steps(counts[solver_name])
        solve = jax.jit(lambda t, s=fixed: rig.solve(t, s))
        compile_times[solver_name] = compile_ms(solve, targets)
        timed[solver_name] = (solve, [(targets,)])
        fixed_half = solver.fixed_steps(counts[solver_name] // 2)
        half = jax.jit(lambda t, s=fixed_half: rig.solve(t, s))
        timed[solver_name, "half"] = (half, [(targets,)])
    times = interleaved_median_ms(timed, repeats, block=3)

    def marginal(name):
        count = counts[name]
        return (times[name] - times[name, "half"]) / (count - count // 2)

    fixed_step = times["fixed_g"] / counts["fixed_g"]
    rows = []
    for solver_name, history in histories.items():
        reached = steps_to_gap(history, minimum)
        step = times[solver_name] / counts[solver_name]
        rows.append({
            "model": name,
            "solver": solver_name,
            "control_vertices": int(rig.energy.num_vertices),
            "steps_recorded": len(history) - 1,
            "final_gap": float((history[-1] - minimum) / minimum),
            "steps_to_gap": reached,
            "ms_to_gap": times[solver_name] if reached is not None else None,
            "step_ms": step,
            "step_in_fixed_g_steps": step / fixed_step,
            "marginal_step_ms": marginal(solver_name),
            "marginal_step_in_fixed_g_steps": marginal(solver_name) / marginal("fixed_g"),
            "compile_ms": compile_times[solver_name],
            # The energy after the sampled steps (all of them would be megabytes).
            "history_steps": sampled_steps(len(history)).tolist(),
            "energy": history[sampled_steps(len(history))].tolist(),
        })
    return {"model": name, "minimum": minimum, "rows": rows}


def format_table(result) -> str:
    fmt = lambda v, spec: "-" if v is None else format(v, spec)  # noqa: E731
    lines = [f"{result['model']} (minimum {result['minimum']:.6g}, "
             f"{result['rows'][0]['control_vertices']} control vertices)",
             "| solver | steps to 1e-6 | time to 1e-6 (ms) | step (ms) | step / fixed-G step | "
             "marginal step / fixed-G's | final gap | compile (ms) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(
            f"| {r['solver']} | {fmt(r['steps_to_gap'], 'd')} | {fmt(r['ms_to_gap'], '.2f')} | "
            f"{r['step_ms']:.4f} | {r['step_in_fixed_g_steps']:.1f} | "
            f"{r['marginal_step_in_fixed_g_steps']:.1f} | {r['final_gap']:.1e} | "
            f"{r['compile_ms']:.0f} |"
        )
    return "\n".join(lines)


def targets_met(result) -> dict:
    """The three targets of the module docstring, measured on this model."""
    rows = {r["solver"]: r for r in result["rows"]}
    fixed = rows["fixed_g"]
    optimistix = [rows[n] for n in ("gauss_newton", "dogleg", "levenberg_marquardt")]
    best = min((r for r in optimistix if r["ms_to_gap"] is not None),
               key=lambda r: r["ms_to_gap"], default=None)
    anderson = rows["anderson"]["steps_to_gap"]
    return {
        "optimistix_step_in_fixed_g_steps": {r["solver"]: r["step_in_fixed_g_steps"]
                                             for r in optimistix},
        "optimistix_marginal_step_in_fixed_g_steps": {
            r["solver"]: r["marginal_step_in_fixed_g_steps"] for r in optimistix},
        "best_optimistix": best and best["solver"],
        "best_optimistix_time_over_fixed_g": (
            best["ms_to_gap"] / fixed["ms_to_gap"]
            if best is not None and fixed["ms_to_gap"] is not None else None),
        "anderson_steps_over_fixed_g": (
            anderson / fixed["steps_to_gap"]
            if anderson is not None and fixed["steps_to_gap"] is not None else None),
    }


def plot(result, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (by_step, by_time) = plt.subplots(1, 2, figsize=(12, 4.5))
    floor = 1e-13  # the gap at float64 round-off, so that the log scale stays finite
    for r in result["rows"]:
        gap = np.maximum((np.asarray(r["energy"]) - result["minimum"]) / result["minimum"], floor)
        steps = np.asarray(r["history_steps"])
        by_step.plot(steps, gap, label=r["solver"])
        by_time.plot(steps * r["step_ms"], gap, label=r["solver"])
    for ax, xlabel in ((by_step, "step"), (by_time, "time (ms)")):
        ax.set_xscale("symlog", linthresh=10 if xlabel == "step" else 1)
        ax.set_yscale("log")
        ax.axhline(GAP, color="grey", lw=0.8, ls="--")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative energy gap to the lowest minimum")
    by_step.legend(fontsize=8)
    fig.suptitle(f"{result['model']}: solvers of the energy (6), float64")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["horse", "character", "flower", "stick"])
    parser.add_argument("--quick", action="store_true", help="the horse only, few repeats")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--json", default="benchmarks/results/solvers-cpu-2core.json")
    parser.add_argument("--figures", default="benchmarks/results/figures")
    args = parser.parse_args(argv)

    import jax

    # The benchmark script, not the library, chooses the precision.
    jax.config.update("jax_enable_x64", True)
    models = ["horse"] if args.quick else args.models
    repeats = 5 if args.quick else args.repeats
    results = []
    for name in models:
        result = run_model(name, repeats)
        result["targets"] = targets_met(result)
        results.append(result)
        print(format_table(result))
        print("targets:", result["targets"])
        if args.figures:
            plot(result, Path(args.figures) / f"solvers-{name}.png")
    write_results(args.json, results, gap=GAP, dtype="float64")
    return 0


if __name__ == "__main__":
    sys.exit(main())
