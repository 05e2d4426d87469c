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
# # A drawing that dances: motion capture from AnimatedDrawings' files
#
# AnimatedDrawings' example character `char1` (its drawing, mask and skeleton), its
# `dab` motion capture clip and its `fair1_ppf` retarget config, as they come from its
# repository (a copy ships with mvcjax's tests, under AnimatedDrawings' MIT licence).
# `motion.Scene.from_files -> scene.deform -> actor.report -> scene.pictures -> write`.

# %%
import pathlib

import matplotlib.pyplot as plt
import numpy as np

import mvcjax
from mvcjax import motion

# The files ship beside mvcjax's tests (a checkout, installed with `pip install -e`); a
# checkout of AnimatedDrawings has the same `examples/` folder.
examples = (pathlib.Path(mvcjax.__file__).parents[1] / "tests" / "data" / "animated_drawings"
            / "examples")
scene = motion.Scene.from_files(examples / "characters" / "char1",
                                examples / "config" / "motion" / "dab.yaml",
                                examples / "config" / "retarget" / "fair1_ppf.yaml")
(actor,) = scene.actors
print(actor.drawing.rig)
print(f"{scene.frames} frames at {scene.fps:.0f} frames a second")

# %% [markdown]
# ## The character, its skeleton and its bones
#
# The mask traced to a shape; a `Bone` per skeleton bone (a bone that would leave the
# shape is pinned at its ends instead); each triangle coloured by the bone nearest it
# inside the shape (the body part whose draw order it follows).

# %%
mesh = actor.drawing.rig.shape_mesh
vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
rest = actor.motion.rest
fig, axes = plt.subplots(1, 2, figsize=(10, 5.5))
axes[0].imshow(actor.drawing.picture, extent=(-0.5, actor.drawing.picture.shape[1] - 0.5,
                                              -0.5, actor.drawing.picture.shape[0] - 0.5))
for child, parent in enumerate(actor.drawing.config.parents):
    if parent >= 0:
        axes[0].plot(*rest[[parent, child]].T, "o-", color="tab:red")
axes[1].tripcolor(*vertices.T, faces, facecolors=actor.drawing.face_joints(faces) % 10,
                  cmap="tab10", edgecolors="none")
for ax in axes:
    ax.set_aspect("equal")
    ax.axis("off")
plt.show()

# %% [markdown]
# ## The clip, posed
#
# Every frame solved by the rig's default solver, then checked: how far the posed
# picture carries each joint from where the clip puts it, and how many triangles fold.

# %%
(poses,) = scene.deform()
report = actor.report(poses)
print(f"joints within {report.joint_miss.max():.2f} px of the retargeted clip; "
      f"{report.folded_frames:.0%} of frames fold, at most {report.flipped.max()} "
      f"of {len(faces)} triangles")
shown = np.linspace(0, scene.frames - 1, 6).round().astype(int)
pictures = scene.pictures([poses[shown]], size=240, progress=False)
fig, axes = plt.subplots(1, len(shown), figsize=(15, 3))
for ax, picture, frame in zip(axes, pictures, shown):
    ax.imshow(picture)
    ax.set_title(f"frame {frame}: {report.flipped[frame]} flipped")
    ax.axis("off")
plt.show()

# %% [markdown]
# ## Where it folds, and `FoldFree`
#
# The dab bends the right elbow until the hand reaches the face: the default solver lets
# triangles at the elbow turn over there. `FoldFree` refuses any fold, and where the
# clip cannot be followed without one it gives way elsewhere: the arm stays short of its
# joints and the body is squeezed. It is also much slower, so it poses only the frames
# around the worst one here.

# %%
worst = int(np.argmax(report.flipped))
window = slice(max(worst - 4, 0), worst + 5)
near = actor.targets(scene.frames)[window]
fold_free = np.asarray(mvcjax.deform_frames(actor.drawing.rig, near, mvcjax.FoldFree()))
free = actor.report(fold_free, frames=np.arange(window.start, window.stop))
print(f"frames {window.start}..{window.stop - 1}: default {report.flipped[window].tolist()} "
      f"flipped; FoldFree {free.flipped.tolist()}, joints within "
      f"{free.joint_miss.max():.1f} px")
both = scene.pictures([np.stack([poses[worst], fold_free[worst - window.start]])], size=300,
                      progress=False)
fig, axes = plt.subplots(1, 2, figsize=(8, 4))
for ax, picture, name in zip(axes, both, ["default", "FoldFree"]):
    ax.imshow(picture)
    ax.set_title(name)
    ax.axis("off")
plt.show()

# %% [markdown]
# ## Written out
#
# `scene.write` draws every frame (each body part in the clip's draw order) and writes a
# GIF, an MP4, an animated PNG or WebP, or a folder of PNG frames. The command line does
# the same: `mvcjax animate CHARACTER MOTION.yaml RETARGET.yaml OUT.gif`.

# %%
out = pathlib.Path("dab.gif")
scene.write(out, vertices=[poses], size=200, progress=False)
print(out, f"{out.stat().st_size / 1e6:.1f} MB")
