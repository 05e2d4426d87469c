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
# # A picture, rigged and animated
#
# A character picture with a transparent background becomes a shape (where it is opaque),
# the shape a rig, and the rig drives the picture: posed, animated, written out as a GIF,
# an SVG outline and a textured OBJ mesh.
# `Shape.from_image(picture) -> Rig.build -> rig.deform / deform_frames ->
# Renderer.build(rig, picture)(vertices) -> mvcjax.export`.

# %%
import pathlib

import jax
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import SVG, Image, display
from matplotlib import patches
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import mvcjax
from mvcjax import datasets, export, plot

# %% [markdown]
# ## A character picture
# Drawn here at run time with matplotlib on a transparent canvas of 300 x 300 pixels:
# coloured parts with outlines, stripes and a face. The axes span
# `(-0.5, 299.5)` both ways, so that the drawing's coordinates are already the shape's:
# the centre of pixel `(row, col)` is `(x, y) = (col, 299 - row)`, y up.

# %%
SIZE = 300
INK, SKIN, SHIRT, STRIPE = "#222222", "#f2c7a5", "#d64545", "#f4e3c1"
TROUSERS, SHOE, HAIR = "#3b5ba5", "#5a3a22", "#6b3f1f"
SHOULDERS = [np.array([120.0, 196.0]), np.array([180.0, 196.0])]  # left, right (as seen)
HIPS = [np.array([133.0, 118.0]), np.array([167.0, 118.0])]
ARM_DOWN = np.radians(35)  # the arms hang 35 degrees below horizontal


def arm_direction(side):
    return np.array([side * np.cos(ARM_DOWN), -np.sin(ARM_DOWN)])


def limb(ax, start, end, width, colour):
    """A rectangle of `width` from `start` to `end`, outlined."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    along = (end - start) / np.hypot(*(end - start))
    across = np.array([-along[1], along[0]]) * width / 2
    ax.add_patch(patches.Polygon([start + across, end + across, end - across, start - across],
                                 facecolor=colour, edgecolor=INK, lw=2))


def draw_character():
    fig = Figure(figsize=(SIZE / 72, SIZE / 72), dpi=72)  # one point is one pixel
    FigureCanvasAgg(fig)
    fig.patch.set_alpha(0.0)  # transparent background
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.set_xlim(-0.5, SIZE - 0.5)
    ax.set_ylim(-0.5, SIZE - 0.5)
    for side, hip in zip((-1, 1), HIPS):  # legs and shoes
        limb(ax, hip + (0, 10), hip - (0, 78), 24, TROUSERS)
        ax.add_patch(patches.Ellipse(hip + (side * 6, -84), 40, 18, facecolor=SHOE,
                                     edgecolor=INK, lw=2))
    for side, shoulder in zip((-1, 1), SHOULDERS):  # sleeve, forearm, hand
        d = arm_direction(side)
        limb(ax, shoulder + 41 * d, shoulder + 84 * d, 15, SKIN)
        limb(ax, shoulder - 4 * d, shoulder + 49 * d, 22, SHIRT)
        ax.add_patch(patches.Circle(shoulder + 88 * d, 10, facecolor=SKIN, edgecolor=INK, lw=2))
    ax.add_patch(patches.Polygon([(118, 138), (182, 138), (188, 108), (112, 108)],
                                 facecolor=TROUSERS, edgecolor=INK, lw=2))
    # The shirt: stripes clipped to its rounded box, then its outline on top.
    box = {"boxstyle": "round,pad=0,rounding_size=12"}
    shirt = ax.add_patch(patches.FancyBboxPatch((120, 132), 60, 72, **box, facecolor=SHIRT,
                                                edgecolor="none"))
    for y in range(140, 204, 14):
        ax.add_patch(patches.Rectangle((110, y), 80, 6, color=STRIPE)).set_clip_path(shirt)
    ax.add_patch(patches.FancyBboxPatch((120, 132), 60, 72, **box, facecolor="none",
                                        edgecolor=INK, lw=2))
    ax.add_patch(patches.Rectangle((120, 128), 60, 8, color=INK))  # belt and buckle
    ax.add_patch(patches.Rectangle((145, 127), 10, 10, facecolor="#e0b040", edgecolor=INK))
    # Neck, face, hair, eyes, cheeks, mouth.
    ax.add_patch(patches.Rectangle((142, 200), 16, 14, facecolor=SKIN, edgecolor=INK, lw=2))
    ax.add_patch(patches.Circle((150, 240), 30, facecolor=SKIN, edgecolor=INK, lw=2))
    ax.add_patch(patches.Wedge((150, 242), 31, 5, 175, facecolor=HAIR, edgecolor=INK, lw=2))
    for side in (-1, 1):
        ax.add_patch(patches.Ellipse((150 + side * 11, 238), 12, 14, facecolor="white",
                                     edgecolor=INK, lw=1.5))
        ax.add_patch(patches.Circle((150 + side * 11, 236), 3.5, color=INK))
        ax.add_patch(patches.Circle((150 + side * 20, 226), 5, color="#f09a9a"))
    ax.add_patch(patches.Arc((150, 228), 20, 12, theta1=200, theta2=340, color=INK, lw=2))
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba()).copy()  # (300, 300, 4) uint8, straight RGBA


picture = draw_character()
rows, cols = picture.shape[:2]
extent = (-0.5, cols - 0.5, -0.5, rows - 0.5)  # imshow in shape coordinates
print(picture.shape, picture.dtype)

fig, ax = plt.subplots(figsize=(4, 4))
ax.imshow(picture, extent=extent)
ax.set_title("the picture (transparent background)")
plt.show()

# %% [markdown]
# ## Its shape
# `Shape.from_image` takes the RGBA array: the shape is where alpha is above 0.5. Its
# outline runs between the opaque and the transparent pixels, on the picture.

# %%
shape = mvcjax.Shape.from_image(picture)
print(shape)

fig, (a, b) = plt.subplots(1, 2, figsize=(9, 4.5))
for ax in (a, b):
    ax.imshow(picture, extent=extent)
    for ring in shape.rings:
        closed = np.vstack([ring, ring[:1]])
        ax.plot(closed[:, 0], closed[:, 1], ".-", color="deepskyblue", linewidth=1.2,
                markersize=6 if ax is b else 0)
a.set_title("outline over the picture")
b.set_xlim(172, 222)
b.set_ylim(150, 200)
b.set_title("the right armpit, close up: vertices dotted")
plt.show()

# %% [markdown]
# ## A rig
# Five bones (spine, arms, legs) and a point on the head. Targets then hold a row for the
# head and two per bone (where its start and end go), in this order.

# %%
HEAD = np.array([150.0, 245.0])
bones = {
    "spine": mvcjax.Bone((150, 118), (150, 190)),
    "left arm": mvcjax.Bone(SHOULDERS[0] + 4 * arm_direction(-1),
                            SHOULDERS[0] + 88 * arm_direction(-1)),
    "right arm": mvcjax.Bone(SHOULDERS[1] + 4 * arm_direction(1),
                             SHOULDERS[1] + 88 * arm_direction(1)),
    "left leg": mvcjax.Bone(HIPS[0], HIPS[0] - (0, 75)),
    "right leg": mvcjax.Bone(HIPS[1], HIPS[1] - (0, 75)),
}
rig = mvcjax.Rig.build(shape, [HEAD, *bones.values()])
rest = np.asarray(rig.handle_positions)
faces = np.asarray(rig.shape_mesh.faces)
ROW = {name: 1 + 2 * i for i, name in enumerate(bones)}  # a bone's start row in the targets
print(rig)

fig, ax = plt.subplots(figsize=(6, 6))
ax.imshow(picture, extent=extent, alpha=0.3)
plot.plot_rig(rig, ax)
ax.set_title("shape mesh (grey), control mesh (blue), bones and head (red)")
plt.show()


# %% [markdown]
# ## A pose
# A bone turns about its start (shoulder or hip): both its targets turn. The picture is
# drawn at the deformed vertices by a `Renderer`, which textures each triangle with the
# picture at its rest position.

# %%
def turn(targets, name, degrees):
    """Targets with bone `name` turned by `degrees` (counter-clockwise) about its start."""
    t = np.array(targets)
    ends = slice(ROW[name], ROW[name] + 2)
    a = np.radians(degrees)
    rotation = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    t[ends] = t[ROW[name]] + (t[ends] - t[ROW[name]]) @ rotation.T
    return t


pose = turn(rest, "right arm", 95)  # waving
pose = turn(pose, "left arm", 25)  # down by the side
pose = turn(pose, "left leg", -12)
pose = turn(pose, "right leg", 8)
pose[0] += (-6.0, -2.0)  # the head leans
# The arm turns far: the default starts from the bones' turns spread over the mesh and
# comes near the minimum (the paper's 15 fixed-G steps from rest, `mvcjax.FixedG()` with
# `init=mvcjax.advanced.RestStart()`, would leave the raised forearm thin and the hand squashed).
posed = rig.deform(pose)

renderer = mvcjax.Renderer.build(rig, picture)  # the picture's size and window
posed_picture = renderer(posed)
checker = mvcjax.Renderer.build(rig, size=(rows, cols), window=(-0.5, -0.5, cols - 0.5,
                                                                  rows - 0.5))

fig, axes = plt.subplots(1, 4, figsize=(16, 4))
axes[0].imshow(picture, extent=extent)
axes[0].set_title("rest")
axes[1].imshow(posed_picture, extent=extent)
axes[1].set_title("posed")
axes[2].imshow(checker(rig.shape_mesh.vertices), extent=extent)
axes[2].set_title("checkerboard at rest")
axes[3].imshow(checker(posed), extent=extent)
axes[3].set_title("checkerboard posed: the stretch and shear")
for ax in axes:
    ax.set_xticks([])
    ax.set_yticks([])
plt.show()

# %% [markdown]
# ## An arm overhead, without folds
# Raised 125 degrees (straight up), the arm is folded at the shoulder by every unconstrained solver:
# the default's minimum has triangles turned inside out (red), and the picture shows the
# shirt overlapping itself at the armpit. `mvcjax.FoldFree()` adds barriers on the
# triangles' areas and a line search that never crosses a flat triangle: no fold, at the
# price of handles a little short of their targets (`info.handle_miss`).

# %%
overhead = turn(rest, "right arm", 125)
panels = {}
for name, solver in [("default", None), ("FoldFree", mvcjax.FoldFree())]:
    args = () if solver is None else (solver,)
    vertices_overhead, info = rig.deform(overhead, *args, return_info=True)
    panels[name] = (vertices_overhead, info)
    print(f"{name:9}: {mvcjax.flipped_triangles(rig.shape_mesh.vertices, vertices_overhead, faces)}"
          f" shape triangles folded, {int(info.inverted)} control triangles inverted, handles"
          f" missed by {float(info.handle_miss):.2f} pixels")

fig, axes = plt.subplots(1, 4, figsize=(17, 5))
for (name, (vertices_overhead, _)), (a, b) in zip(panels.items(),
                                                  [axes[:2], axes[2:]]):
    a.imshow(renderer(vertices_overhead), extent=extent)
    a.set_title(f"{name}: the picture")
    plot.plot_mesh(vertices_overhead, faces, b, color="0.6", linewidth=0.2)
    folded = plot.plot_folds(rig, vertices_overhead, b)
    b.set_title(f"{name}: {folded} triangles folded (red)")
    b.set_xlim(140, 240)  # the right shoulder, close up
    b.set_ylim(160, 260)
for ax in axes:
    ax.set_xticks([])
    ax.set_yticks([])
plt.show()

# %% [markdown]
# ## Draw order
# When a part swings over another, two triangles cover the same pixels. By default the
# order is decided once, from the rest mesh (`core_depth`): what lies farther from the
# shape's core along the shape is on top, so the arm passes in front of the body, and
# the order is the same in every frame. `depth=` gives an order of one's own instead, a
# number per rest vertex (larger on top), which `depth_from_handles` spreads from a
# number per handle: here the arms are at depth 0 and the rest of the body at 1, so
# that the arm passes behind it.
#
# The arm turns 90 degrees. Much further the solvers fold the armpit over onto itself:
# the energy keeps lengths and shapes but has no term against mirrored triangles (the
# next section raises the arm overhead without folds).

# %%
across = turn(rest, "right arm", -90)  # the hand goes to the buckle, across the shirt
crossed = rig.deform(across, mvcjax.GaussNewton())


# A depth per target row (the arms' at 0, the rest at 1), spread over the mesh: every
# vertex takes the depth of the handle nearest to it along the shape.
depths = np.ones(len(rest))
for name in ("left arm", "right arm"):
    depths[ROW[name]:ROW[name] + 2] = 0.0
depth = mvcjax.depth_from_handles(rig, depths)
behind = mvcjax.Renderer.build(rig, picture, depth=depth)
arms = depth < 0.5  # the arms' vertices (nearer their handles, a little higher than 0)

fig, axes = plt.subplots(1, 3, figsize=(12, 4))
on_arm = arms[faces].all(axis=1)
plot.plot_mesh(crossed, faces[~on_arm], axes[0], color="0.6")
plot.plot_mesh(crossed, faces[on_arm], axes[0], color="tab:red")
axes[0].set_title("the arms' triangles in red")
axes[1].imshow(renderer(crossed), extent=extent)
axes[1].set_title("default: farther from the core on top")
axes[2].imshow(behind(crossed), extent=extent)
axes[2].set_title("depth=: the arm behind the body")
for ax in axes:
    ax.set_xlim(60, 240)
    ax.set_ylim(80, 280)
    ax.set_xticks([])
    ax.set_yticks([])
plt.show()

# %% [markdown]
# ## An animation
# Two seconds at 24 frames per second: the right arm waves, the left arm swings, the
# legs step in turn, the head sways. The targets are smooth functions of time, periodic
# so that the animation loops. `deform_frames` solves all frames in one compiled program;
# `jax.vmap(renderer)` draws them, in a window that `fit_window` fits around every frame.

# %%
FRAMES = 48
phase = 2 * np.pi * np.arange(FRAMES) / FRAMES
targets = []
for p in phase:
    t = turn(rest, "right arm", 75 + 20 * np.sin(2 * p))  # raised, waving twice a loop
    t = turn(t, "left arm", 12 * np.sin(p))
    for name, side, lift in (("left leg", -1, max(np.sin(p), 0)),
                             ("right leg", 1, max(-np.sin(p), 0))):
        t = turn(t, name, side * 8 * lift)  # a step in place: the leg lifts and turns out
        t[ROW[name]:ROW[name] + 2] += (0, 10 * lift)
    t[0] += (4 * np.sin(p), 0)
    targets.append(t)
targets = np.stack(targets)  # (48, 11, 2)

vertices = mvcjax.deform_frames(rig, targets, mvcjax.GaussNewton())
print(vertices.shape)

window = mvcjax.fit_window(vertices, size=(rows, cols))  # holds the raised hand too
animation = mvcjax.Renderer.build(rig, picture, size=(rows, cols), window=window)
# vmap draws the frames together; a dozen at a time keeps the memory small.
pictures = np.concatenate([jax.vmap(animation)(chunk) for chunk in np.split(vertices, 4)])

outputs = pathlib.Path("outputs")  # next to the notebook
outputs.mkdir(exist_ok=True)
export.write_animation(outputs / "pictures-walk.gif", pictures, fps=24)
print(f"{(outputs / 'pictures-walk.gif').stat().st_size / 1e3:.0f} kB")
display(Image(filename=outputs / "pictures-walk.gif", embed=True))

# %% [markdown]
# ## A character in layers
# Drawn as one silhouette, an arm that lies over the torso at rest is welded to it. Drawn
# in layers (a body, two arms, and a right hand of its own), each layer is a part with its
# own meshes, all posed by one set of handles: a bone along each arm (its shoulder, inside
# the torso too, pins the torso there), a point on the chest and one on each ankle. The
# right hand holds no handle and follows the arm it overlaps. `layers` could as well be a
# Photoshop or OpenRaster file (`mvcjax.load_layers`).

# %%
layers = datasets.layered_figure()
character = mvcjax.Character.build(layers, datasets.layered_figure_handles())
print(character)
wave = datasets.layered_figure_wave(30)  # the right arm across the chest and back
parts = mvcjax.deform_frames(character, wave)
drawn = mvcjax.Renderer.build(character, layers, background=(1, 1, 1, 1))
# Each frame may have its own draw order: in the second half the body goes on top of the
# left arm, which then hangs behind it.
orders = np.where(np.arange(30)[:, None] < 15, [0, 1, 2, 3], [1, 0, 2, 3])
waving = drawn.frames(parts, order=orders)
export.write_animation(outputs / "pictures-layers.gif", waving, fps=15)

fig, axes = plt.subplots(1, 4, figsize=(12, 4))
for ax, k in zip(axes, (0, 8, 15, 24)):
    ax.imshow(waving[k])
    ax.set_title(f"frame {k}, order {orders[k].tolist()}")
    ax.axis("off")
plt.show()
display(Image(filename=outputs / "pictures-layers.gif", embed=True))

# %% [markdown]
# ## Outline and mesh
# `outline_rings` gives the deformed mesh's boundary, `write_svg` writes it as a vector
# outline (y flipped for the screen); `write_obj` writes the mesh with texture coordinates
# on the picture (`texture_uv` of the rest vertices), so that a 3D program can texture
# it with the picture saved as PNG.

# %%
frame = vertices[6]  # the hand at the top of its wave
export.write_svg(outputs / "pictures-pose.svg", export.outline_rings(frame, faces),
                 fill="#d64545", stroke="#222222")
export.write_image(outputs / "pictures.png", picture)
export.write_obj(outputs / "pictures-pose.obj", frame, faces,
                 texture_coordinates=export.texture_uv(rig.shape_mesh.vertices, rows, cols))
for path in sorted(outputs.glob("pictures*")):
    print(f"{path.name:20} {path.stat().st_size / 1e3:6.0f} kB")
display(SVG(filename=outputs / "pictures-pose.svg"))
print(*(outputs / "pictures-pose.obj").read_text().splitlines()[:2], "...", sep="\n")

# %% [markdown]
# ## A limb bent far: the paper's energy, the default, FoldFree
# The sprite's right arm raised 150 degrees about the shoulder, and the letter K's top
# bent 90 degrees about its middle, posed three ways: the paper's energy
# (`Weights.paper()`, 100 fixed-G steps), the default as-rigid-as-possible energy, and
# `FoldFree()`. The triangles a pose turns inside out are counted, and drawn red over
# the posed mesh (`plot.plot_folds`).


# %%
def turned(point, centre, degrees):
    t = np.radians(degrees)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return centre + (np.asarray(point) - centre) @ rot.T


sprite, sprite_handles = datasets.sprite(), datasets.sprite_handles()
arm = np.array(mvcjax.Rig.build(sprite, sprite_handles).handle_positions)
arm[4] = turned(arm[4], arm[3], 150)  # the right wrist about the right shoulder

letter = datasets.glyph("K")
levels = datasets.glyph_handles(letter)
pins = np.concatenate(levels)
middle, top = len(levels[0]), len(levels[0]) + len(levels[1])
bend = pins.copy()
bend[top:] = turned(pins[top:], pins[middle:top].mean(axis=0), 90)

ways = {"paper's energy": (mvcjax.Weights.paper(), mvcjax.FixedG(iterations=100)),
        "default": (mvcjax.Weights(), mvcjax.FixedG(iterations=30)),
        "FoldFree": (mvcjax.Weights(), mvcjax.FoldFree())}
fig, axes = plt.subplots(2, 3, figsize=(12, 8))
for row, (shape, handles, targets) in enumerate([(sprite, sprite_handles, arm),
                                                 (letter, pins, bend)]):
    for ax, (name, (weights, solver)) in zip(axes[row], ways.items()):
        posed_rig = mvcjax.Rig.build(shape, handles, weights=weights)
        solved = posed_rig.deform(targets, solver)
        plot.plot_deformation(posed_rig, solved, targets, ax=ax)
        flipped = plot.plot_folds(posed_rig, solved, ax=ax)
        ax.set_title(f"{name}: {flipped} flipped")
        ax.axis("off")
plt.show()
