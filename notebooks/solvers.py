# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Solvers of the energy compared
#
# Every solver minimises the same energy (6) behind one interface,
# `rig.solve(targets, solver, return_info=True)`:
#
# - `FixedG()`: the paper's local-global iteration `V <- G b(V)`, cheap steps and
#   linear convergence; `FixedG(anderson=m)` mixes the last `m` steps (Anderson
#   acceleration, with an energy check and restarts);
# - `GaussNewton()`, `Dogleg()`, `LevenbergMarquardt()`: optimistix's methods on the
#   residuals. The Jacobian `A - db/dV` is never formed: each step runs a few conjugate
#   gradients on the Gauss-Newton matrix, kept as the rig's constant normal matrix
#   `N = A^T W A` (the matrix behind `G`) less the rotation terms, preconditioned by
#   `N` and deflated by the previous step (`mvcjax.advanced.StructuredCG()`, the default
#   `linear_solver`). `linear_solver=lx.Cholesky()` is the dense alternative;
# - `JaxoptGaussNewton()`, `JaxoptLevenbergMarquardt()`: jaxopt's, on a dense Jacobian.
#
# This notebook runs them on the horse, records the energy after every step with
# `rig.energy_history`, and times them. `benchmarks/solvers.py` does the same on all
# four models, and its committed results close the notebook. Float64 throughout: a
# relative energy gap of 1e-6 is below what float32 resolves.

# %%
import json
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

import mvcjax  # noqa: E402
from mvcjax import datasets  # noqa: E402

model = datasets.model("horse")
rig = model.rig(dtype=jnp.float64, weights=mvcjax.Weights.paper())  # the paper's energy
targets = rig.handle_positions + jnp.asarray(model.drag)
print(rig)

# %% [markdown]
# ## Solved to their own tolerances
# Each solver's defaults: `converged`, the steps taken and the energy reached. `FixedG()`
# alone is the paper's 15 steps, which stop short, and says so.

# %%
solvers = {
    "fixed_g (15 steps)": mvcjax.FixedG(),
    "fixed_g": mvcjax.FixedG(iterations=10000, stop_early=True),
    "anderson": mvcjax.FixedG(iterations=2000, stop_early=True, anderson=5),
    "gauss_newton": mvcjax.GaussNewton(),
    "dogleg": mvcjax.Dogleg(),
    "levenberg_marquardt": mvcjax.LevenbergMarquardt(),
    "jaxopt_levenberg_marquardt": mvcjax.advanced.JaxoptLevenbergMarquardt(),
}


def median_ms(f, *args, repeats=20):
    jax.block_until_ready(f(*args))  # compile outside the timed region
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(f(*args))
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


print(f"{'solver':28} converged  steps      energy   time (ms)")
for name, solver in solvers.items():
    solve = jax.jit(lambda t, s=solver: rig.solve(t, s, return_info=True))
    _, info = solve(targets)
    ms = median_ms(solve, targets, repeats=5)
    print(f"{name:28} {bool(info.converged)!s:9} {int(info.iterations):6d} "
          f"{float(info.energy):11.6f} {ms:10.2f}")

# %% [markdown]
# ## Energy against step
# `rig.energy_history` runs a fixed number of steps with the stopping criteria off and
# returns the energy after each. The reference minimum is the lowest energy any solver
# reached; the gap is relative to it.

# %%
recorded = {
    "fixed_g": (mvcjax.FixedG(unroll=0), 4000),
    "anderson": (mvcjax.FixedG(anderson=5, unroll=0), 300),
    "gauss_newton": (mvcjax.GaussNewton(), 150),
    "dogleg": (mvcjax.Dogleg(), 150),
    "levenberg_marquardt": (mvcjax.LevenbergMarquardt(), 150),
    "jaxopt_levenberg_marquardt": (mvcjax.advanced.JaxoptLevenbergMarquardt(), 60),
}
histories = {
    name: np.asarray(jax.jit(lambda t, s=s, n=n: rig.energy_history(t, s, n))(targets))
    for name, (s, n) in recorded.items()
}
minimum = min(h.min() for h in histories.values())
gaps = {name: (h - minimum) / minimum for name, h in histories.items()}


def steps_to(gap, level=1e-6):
    reached = np.flatnonzero(gap <= level)
    return int(reached[0]) if reached.size else None


to_gap = {name: steps_to(gap) for name, gap in gaps.items()}
print("steps to a relative gap of 1e-6:", to_gap)

# %% [markdown]
# ## Time per step, and energy against time
# A step of each solver is timed as the benchmark does: a solve of exactly the steps it
# needed to reach the gap (`solver.fixed_steps(n)`: the same solver, its stopping
# criteria off), compiled first, median of several calls, divided by the steps. The
# solvers are timed in turns, so that whatever else the machine does weighs on all of
# them alike and their ratios come from one run.

# %%
timed = {}
for name, (solver, recorded_steps) in recorded.items():
    steps = to_gap[name] or recorded_steps
    fixed = solver.fixed_steps(steps)
    timed[name] = (jax.jit(lambda t, s=fixed: rig.solve(t, s)), steps)
    jax.block_until_ready(timed[name][0](targets))  # compile outside the timed region
times = {name: [] for name in timed}
for _ in range(7):
    for name, (solve, _) in timed.items():
        start = time.perf_counter()
        jax.block_until_ready(solve(targets))
        times[name].append(time.perf_counter() - start)
step_ms, time_to_gap = {}, {}
for name, (_, steps) in timed.items():
    ms = 1e3 * float(np.median(times[name]))
    step_ms[name] = ms / steps
    time_to_gap[name] = ms if to_gap[name] is not None else None

fixed_step = step_ms["fixed_g"]
print(f"{'solver':28} steps to 1e-6  time to 1e-6 (ms)  step (ms)  step / fixed-G step")
for name in recorded:
    t = "-" if time_to_gap[name] is None else f"{time_to_gap[name]:.2f}"
    print(f"{name:28} {to_gap[name]!s:>13} {t:>18} {step_ms[name]:10.4f} "
          f"{step_ms[name] / fixed_step:20.1f}")

# %%
fig, (by_step, by_time) = plt.subplots(1, 2, figsize=(13, 4.5))
for name, gap in gaps.items():
    steps = np.arange(len(gap))
    shown = np.maximum(gap, 1e-13)  # float64 round-off, so that the log scale stays finite
    by_step.plot(steps, shown, label=name)
    by_time.plot(steps * step_ms[name], shown, label=name)
for ax, label in ((by_step, "step"), (by_time, "time (ms)")):
    ax.set_xscale("symlog", linthresh=10 if label == "step" else 1)
    ax.set_yscale("log")
    ax.axhline(1e-6, color="grey", lw=0.8, ls="--")
    ax.set_xlabel(label)
    ax.set_ylabel("relative energy gap")
by_step.legend(fontsize=8)
fig.suptitle("horse: the energy (6) against step and against time")
plt.show()

# %% [markdown]
# The structured Gauss-Newton steps cost about 7 to 12 fixed-G steps each, depending on
# the solver and the run (a dense Jacobian with Cholesky costs hundreds, see the table
# below), and they get to the gap in tens of steps where fixed-G needs thousands.
# Anderson's steps cost about three plain ones, and it needs a twentieth of them.
#
# The energy is not convex: from the same start the solvers can settle in different
# stationary points (on this drag they all find the same one). `tests/test_solvers.py`
# shows a drag where they do not, and that each returns to the lowest minimum when
# started near it.

# %% [markdown]
# ## Gradients through the solvers
# At convergence the solvers return the same minimum, so their implicit gradients agree
# (optimistix's, and `FixedG(adjoint=optx.ImplicitAdjoint())`'s, here with Anderson
# acceleration). The unrolled
# gradient of a plain `FixedG` is the exact derivative of what its loop computed: after
# 3000 steps, which on this drag are not yet at the minimum (see the plot above), it
# differs from them in the fourth digit.

# %%
def landmark_loss(t, solver):
    return jnp.sum(rig.deform(t, solver)[::50] ** 2) / 1e4


for name, solver in {
    "fixed_g (unrolled, 3000 steps)": mvcjax.FixedG(iterations=3000, unroll=0),
    "anderson (implicit)": mvcjax.FixedG(iterations=5000, rtol=1e-12, stop_early=True,
                                         anderson=5, adjoint=optx.ImplicitAdjoint()),
    "gauss_newton (implicit)": mvcjax.GaussNewton(),
}.items():
    _, info = rig.solve(targets, solver, return_info=True)
    g = jax.jit(jax.grad(landmark_loss), static_argnums=1)(targets, solver)
    print(f"{name:32} converged {bool(info.converged)!s:5}  "
          f"d loss / d targets[0] = {np.asarray(g[0]).round(8)}")

# %% [markdown]
# ## The benchmark's results
# `python benchmarks/solvers.py` measured these on a 2-core CPU (the JSON and the
# figures are in `benchmarks/results/`).

# %%
results_path = (pathlib.Path(mvcjax.__file__).parent.parent / "benchmarks" / "results"
                / "solvers-cpu-2core.json")
if results_path.exists():
    results = json.loads(results_path.read_text())
    for result in results["rows"]:
        print(f"\n{result['model']}: minimum {result['minimum']:.6g}")
        print(f"{'solver':28} steps to 1e-6  time to 1e-6 (ms)  step / fixed-G step  compile (ms)")
        for r in result["rows"]:
            t = "-" if r["ms_to_gap"] is None else f"{r['ms_to_gap']:.2f}"
            print(f"{r['solver']:28} {r['steps_to_gap']!s:>13} {t:>18} "
                  f"{r['step_in_fixed_g_steps']:20.1f} {r['compile_ms']:13.0f}")
else:
    print("run `python benchmarks/solvers.py` to produce", results_path)
