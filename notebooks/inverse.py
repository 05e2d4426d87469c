# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # An inverse problem: pose the horse by its landmarks
#
# `rig.deform` maps handle targets to a deformed shape. Often the question runs the other
# way: points of the shape that are *not* handles (the tip of an ear, the tail) should
# reach given places; where must the handles go? With `t` the `(h, 2)` handle targets,
# `D(t)` the deformed shape mesh, `L` a few landmark vertices and `g` their goals, solve
#
# $$\min_t \; \sum_{l \in L} \| D(t)_l - g_l \|^2 + \lambda^2 \, \| t - t_\mathrm{rest} \|^2 .$$
#
# The horse has 5 handles (10 unknowns) and we ask for 2 landmarks (4 equations): many
# poses hit the goals, and the small regulariser ($\lambda = 10^{-3}$) picks the one that
# moves the handles least. A Gauss-Newton-type solver needs the Jacobian `dD(t)_L / dt`,
# through the nonlinear solve of the energy. Without derivatives, that is 20 more
# deformations per step by finite differences, and a step size to guess; here JAX
# differentiates `rig.deform` exactly, and optimistix does the rest.

# %%
import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402

import mvcjax  # noqa: E402
from mvcjax import datasets, plot  # noqa: E402

# %% [markdown]
# ## Landmarks and goals
# The landmarks are extreme points of the rest shape mesh: its highest point (the tip of
# the ear) and its left-most point (the back of the tail). The goals raise the head by
# 25 units and swing the tail out by 20 and up by 10.

# %%
shape = datasets.horse()
rig = mvcjax.Rig.build(shape, datasets.horse_handles())
rest = np.asarray(rig.shape_mesh.vertices)
handle_names = ["front hoof", "hind hoof", "hind hoof", "back", "head"]
diagonal = shape.diagonal

landmark_names = ["ear tip", "tail"]
landmarks = np.array([np.argmax(rest[:, 1]), np.argmin(rest[:, 0])])
assert not np.isin(landmarks, np.asarray(rig.shape_mesh.handles)).any()
goals = rest[landmarks] + np.array([[0.0, 25.0], [-20.0, 10.0]])
for name, i, g in zip(landmark_names, landmarks, goals):
    print(f"{name:8} vertex {i:4d} at {rest[i].round(1)} -> goal {g.round(1)}")
print(rig, f"bounding-box diagonal {diagonal:.1f}")

# %% [markdown]
# ## Solve
# The deformation is `rig.deform`'s default: the paper's 15 fixed-G iterations, a fixed
# loop that JAX differentiates by unrolling, in forward and in reverse mode. So
# optimistix's default forward-mode Jacobian (`jac="fwd"`: one JVP per unknown) works.
# (The converged `mvcjax.GaussNewton()`, whose gradients are implicit, needs
# `options=dict(jac="bwd")` here: optimistix's forward-mode Jacobian of an optimistix
# solve nested in its Levenberg-Marquardt fails in lineax with non-finite values.)
#
# The targets found are right for this deformation, not for another solver: the last
# line deforms them with the converged `GaussNewton()`, which puts the landmarks
# elsewhere. The callback records the largest landmark error at the point each step
# evaluates, for the plot below.

# %%
solver = mvcjax.FixedG()
regulariser = 1e-3
rest_targets = rig.handle_positions


def residuals(targets, goals):
    reached = rig.deform(targets, solver)[landmarks]
    return jnp.concatenate([(reached - goals).ravel(),
                            regulariser * (targets - rest_targets).ravel()])


def loss(targets):
    return 0.5 * jnp.sum(residuals(targets, goals) ** 2)


history = []


def recorded(targets, goals):
    r = residuals(targets, goals)
    error = jnp.linalg.norm(r[: goals.size].reshape(goals.shape), axis=1).max()
    jax.debug.callback(lambda x: history.append(float(x)), error)
    return r


sol = optx.least_squares(recorded, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8),
                         rest_targets, args=jnp.asarray(goals), max_steps=200, throw=False)
targets = sol.value
converged = bool(sol.result == optx.RESULTS.successful)
deformed = np.asarray(rig.deform(targets, solver))
reached = deformed[landmarks]
err = np.linalg.norm(reached - goals, axis=1).max()
print(f"steps: {int(sol.stats['num_steps'])}, converged: {converged}")
print(f"largest landmark error: {err:.2e} units = {err / diagonal:.1e} of the diagonal")
for name, p, q in zip(handle_names, np.asarray(rest_targets), np.asarray(targets)):
    print(f"  {name:10} handle at {p.round(1)} moved by {(q - p).round(1)}")
assert converged
assert err < 1e-5 * diagonal  # the regulariser's pull leaves about 1e-4 units
converged_pose = np.asarray(rig.deform(targets, mvcjax.GaussNewton()))
print("the same targets solved to convergence miss the goals by",
      np.linalg.norm(converged_pose[landmarks] - goals, axis=1).round(1), "units")

# %% [markdown]
# ## Check the gradient
# The derivative of the loss along a random direction, by forward mode (`jax.jvp`, what
# the solver used), by reverse mode (`jax.grad`) and by central finite differences, at
# the start (the rest targets).

# %%
direction = jax.random.normal(jax.random.key(0), rest_targets.shape, rest_targets.dtype)
forward = float(jax.jvp(loss, (rest_targets,), (direction,))[1])
reverse = float(jnp.sum(jax.grad(loss)(rest_targets) * direction))
h = 1e-4
central = float((loss(rest_targets + h * direction) - loss(rest_targets - h * direction)) / (2 * h))
print(f"forward {forward:.10g}  reverse {reverse:.10g}  finite differences {central:.10g}")
print(f"relative error of forward mode: {abs(forward - central) / abs(central):.1e}, "
      f"forward vs reverse: {abs(forward - reverse) / abs(reverse):.1e}")
assert abs(forward - central) < 1e-6 * abs(central)

# %% [markdown]
# ## The pose found
# Left, the rest shape with its handles (red) and the landmarks (blue) with arrows to
# their goals. Middle, the solution: the deformed shape mesh over the rest one, the
# optimised handle targets (black crosses, arrows from the rest handles), the goals
# (stars) and where the landmarks landed (blue dots). Right, the largest landmark error
# at the point each step tried: on the goals after a handful of steps, the solver spends
# the rest creeping along the flat valley of the regulariser until successive iterates
# agree to its tolerance.

# %%
fig, (a, b, c) = plt.subplots(1, 3, figsize=(17, 5.5), width_ratios=[1, 1, 0.8])
handles_rest = np.asarray(rest_targets)
plot.plot_mesh(rest, rig.shape_mesh.faces, a, color="0.6", linewidth=0.25)
a.plot(*handles_rest.T, "o", color="tab:red", markersize=5, label="handles")
a.plot(*rest[landmarks].T, "o", color="tab:blue", markersize=5, label="landmarks")
a.plot(*goals.T, "*", color="tab:orange", markersize=12, label="goals")
for p, q in zip(rest[landmarks], goals):
    a.annotate("", q, p, arrowprops=dict(arrowstyle="->", color="tab:orange"))
a.set_title("rest pose, landmarks and goals")
a.legend(loc="upper left", fontsize=8)

plot.plot_deformation(rig, deformed, targets, b)
for p, q in zip(handles_rest, np.asarray(targets)):
    b.annotate("", q, p, arrowprops=dict(arrowstyle="->", color="k", linewidth=0.8))
b.plot(*goals.T, "*", color="tab:orange", markersize=12)
b.plot(*reached.T, "o", color="tab:blue", markersize=4)
b.set_title("solution: optimised targets, landmarks on their goals")
points = np.concatenate([rest, deformed, goals])
for ax in (a, b):
    ax.set_xlim(points[:, 0].min() - 10, points[:, 0].max() + 10)
    ax.set_ylim(points[:, 1].min() - 10, points[:, 1].max() + 10)

c.semilogy(history, ".-", color="tab:green")
c.set_xlabel("step")
c.set_ylabel("largest landmark error (units)")
fig.tight_layout()
plt.show()
