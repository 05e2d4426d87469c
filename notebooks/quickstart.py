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
# # mvcjax quickstart
#
# A shape, a few handles, a drag: the deformed shape, as rigid as it can be.
# The data flows `Shape -> Rig.build (shape mesh, control mesh, MVC weights, G) ->
# rig.solve -> rig.skin`, and everything from the rig on is JAX: it jits, vmaps and
# differentiates.

# %%
import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import mvcjax
from mvcjax import datasets, plot

# %% [markdown]
# ## A shape and its rig
# The built-in horse is the silhouette of `skimage.data.horse()`. Any binary image works
# through `Shape.from_image`, any polygon (with holes) through `Shape.from_polygon`.

# %%
shape = datasets.horse()
handles = datasets.horse_handles()
rig = mvcjax.Rig.build(shape, handles)
print(shape)
print(rig)

# %% [markdown]
# The control mesh (blue) is small: an enclosing polygon `V_CP` that follows the shape's
# concavities and runs *into* the one-pixel slot between the front legs rather than
# across it, and inner vertices `V_CG` picked among the shape mesh's vertices.

# %%
fig, (a, b) = plt.subplots(1, 2, figsize=(12, 5))
plot.plot_rig(rig, a)
a.set_title("shape mesh under control mesh")
plot.plot_rig(rig, b)
b.set_xlim(235, 300)
b.set_ylim(5, 95)
b.set_title("the front legs: the slot stays open")
plt.show()

# %% [markdown]
# ## Drag the handles
# Targets are one `(x, y)` per handle. `rig.deform` solves the energy on the control
# mesh (the paper's 15 fixed-G iterations by default) and carries the shape mesh with
# mean value coordinates.

# %%
targets = rig.handle_positions + datasets.horse_drag()
deformed = rig.deform(targets)

fig, ax = plt.subplots(figsize=(7, 5))
plot.plot_deformation(rig, deformed, targets, ax)
plt.show()

# %% [markdown]
# ## Drag them with the mouse
# `mvcjax.interact(rig)` opens a figure in which every handle's target is a red dot:
# press on one and drag, and the horse follows while the mouse moves. A click on the
# horse adds a pin there, a right-click on a dot removes it, without a pause. In
# Jupyter it needs ipympl: `pip install 'mvcjax[widget]'`, then run
# `%matplotlib widget` in a cell first; in a script, a desktop window opens at
# `plt.show()`. This notebook was run with the inline backend, which stores a still
# picture, so the cell below moves the targets from code instead of the mouse.
# The session keeps the pose (`posing.targets`, `posing.shape_vertices`) and, with
# `record=True`, the whole drag (`posing.write_animation("drag.gif")`).

# %%
posing = mvcjax.interact(rig, record=True)
posing.set_targets(targets)  # where a drag of the dots would leave them
print(posing.targets.round(1))
print("the pose is rig.deform(targets):",
      bool(np.allclose(posing.shape_vertices, deformed, atol=1e-3)))
plt.show()

# %% [markdown]
# ## Bones: pose with segments
# A handle can also be a bone, `mvcjax.Bone(start, end)`: the shape along the segment
# follows it as a rigid segment (or stretches with it: `Bone(start, end, stretch=True)`).
# Bones and point handles mix; the targets then hold a row per point handle and two per
# bone, where its start and its end go, in the order the handles were given. Here the
# character's spine and right arm are bones; the arm is raised about the shoulder and
# the spine leans, while the head, left wrist and ankles hold.

# %%
character = datasets.model("character")
head, pelvis, left_wrist, right_wrist, left_ankle, right_ankle = character.handles
shoulder = np.array([22.0, 139.0])
bone_rig = mvcjax.Rig.build(character.shape, [
    head, mvcjax.Bone(pelvis, (0.0, 150.0)), mvcjax.Bone(shoulder, right_wrist),
    left_wrist, left_ankle, right_ankle,
])
print(bone_rig)


def turned(point, centre, degrees):
    t = np.radians(degrees)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return centre + rot @ (point - centre)


pose = np.array(bone_rig.handle_positions)  # head, spine (2), arm (2), wrist, ankles
pose[2] = turned(pose[2], pose[1], -12.0)  # the spine leans right
pose[0] = turned(pose[0], pose[1], -12.0)  # and the head with it
pose[3] = turned(pose[3], pose[1], -12.0)  # the shoulder goes along
pose[4] = turned(right_wrist, shoulder, 60.0) + (pose[3] - shoulder)  # the arm is raised
# A large turn: the paper's 15 fixed-G steps leave the armpit pinched; Gauss-Newton
# solves it.
posed = bone_rig.deform(pose, mvcjax.GaussNewton())

fig, (a, b) = plt.subplots(1, 2, figsize=(10, 5))
plot.plot_rig(bone_rig, a)
a.set_title("rest: bones and points (red)")
plot.plot_deformation(bone_rig, posed, pose, b)
b.set_title("posed: the arm raised, the spine leaning")
plt.show()

# %% [markdown]
# ## Solvers
# The paper's 15 fixed-G steps are fast but not converged. Anderson acceleration or
# Gauss-Newton (through optimistix) solve to a tolerance; each reports whether it
# converged. The energy has several minima: different solvers may settle in different
# ones (see the README).

# %%
for solver in [mvcjax.FixedG(), mvcjax.FixedG(iterations=2000, anderson=5, stop_early=True),
               mvcjax.GaussNewton()]:
    _, info = rig.solve(targets, solver, return_info=True)
    print(f"{solver!r:60.60}  converged={bool(info.converged)!s:5}  "
          f"iterations={int(info.iterations):4d}  energy={float(info.energy):.4f}")

# %% [markdown]
# ## Many frames at once, and gradients
# `vmap` over a leading axis of targets gives a batch of frames; `grad` differentiates
# any loss of the deformed shape with respect to the targets.

# %%
steps = jnp.linspace(0.0, 1.0, 6)
frames = rig.handle_positions + steps[:, None, None] * datasets.horse_drag()
animation = jax.jit(jax.vmap(rig.deform))(frames)
print(animation.shape)

fig, axes = plt.subplots(1, 6, figsize=(18, 3))
for ax, frame, t in zip(axes, animation, frames):
    plot.plot_deformation(rig, frame, t, ax, rest=False)
plt.show()

# %%
nose = int(np.argmax(np.asarray(rig.shape_mesh.vertices)[:, 0]))  # the right-most point


def nose_height(t):
    return rig.deform(t)[nose, 1]


print("d(nose y)/d(targets):\n", np.round(jax.grad(nose_height)(targets), 3))
