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
# # The paper, reproduced: figures 3 to 5 and Table 1
#
# Yoo, Choi and Shin solve the nonlinear energy of Weng et al. on a small **control
# mesh** and carry a dense **shape mesh** with mean value coordinates. Their figures
# compare, under the same drag:
#
# - (ga) the input, with its shape mesh and control mesh;
# - (na) **control mesh only**: the shape mesh carried by barycentric coordinates of its
#   control triangle (`Rig.build(..., skinning=mvcjax.advanced.BarycentricSkinning())`);
# - (da) **control mesh + MVC**, the paper's method (`Rig.build(...)`; mvcjax's default
#   skinning is a continuous blend of the MVC,
#   `skinning=mvcjax.advanced.MVCSkinning()` is the paper's own);
# - (ra) the **full solve**: the same energy on the shape mesh itself
#   (`Rig.build(..., control=mvcjax.FullSolve())`).
#
# Every rig is built through the same `Rig.build` with the paper's energy
# (`weights=mvcjax.Weights.paper()`; mvcjax's default is the as-rigid-as-possible energy)
# and deformed with the same `rig.deform(targets, mvcjax.FixedG())`, the paper's 15
# fixed-G iterations from the same start.

# %%
import json
import pathlib

import matplotlib.pyplot as plt
import numpy as np

import mvcjax
from mvcjax import datasets, plot

# %% [markdown]
# ## The four models
# The character, flower and stick are built-in shapes sized like the paper's (shape
# meshes of about 532, 730 and 229 vertices, control meshes of about 66, 120 and 43);
# the horse is `skimage.data.horse()`.


# %%
def compare(name):
    """Build the four rigs of a model, deform them under its default drag, and measure."""
    model = datasets.model(name)
    paper = mvcjax.Weights.paper()
    rigs = {
        "(na) control mesh only": model.rig(skinning=mvcjax.advanced.BarycentricSkinning(),
                                            weights=paper),
        "paper's MVC": model.rig(skinning=mvcjax.advanced.MVCSkinning(), weights=paper),
        "(da) control mesh + MVC": model.rig(weights=paper),
        "(ra) full solve": mvcjax.Rig.build(
            model.shape, model.handles, control=mvcjax.FullSolve(), weights=paper,
            shape_spacing=model.options.get("shape_spacing"),
        ),
    }
    ours = rigs["(da) control mesh + MVC"]
    targets = ours.handle_positions + model.drag
    out = {key: np.asarray(rig.deform(targets, mvcjax.FixedG())) for key, rig in rigs.items()}
    rest = np.asarray(ours.shape_mesh.vertices)
    faces = np.asarray(ours.shape_mesh.faces)
    full = out["(ra) full solve"]
    rows = []
    for key, result in out.items():
        mean, worst = mvcjax.advanced.difference(result, full, rest)
        rows.append((key, mean, worst, mvcjax.advanced.smoothness(rest, result, faces),
                     mvcjax.flipped_triangles(rest, result, faces)))
    return ours, targets, out, rows


def show(name):
    rig, targets, out, rows = compare(name)
    print(rig)
    panels = {k: v for k, v in out.items() if k != "paper's MVC"}
    plot.plot_comparison(rig, panels, np.asarray(targets))
    plt.show()
    print(f"{'method':26} {'diff to (ra) mean':>18} {'max':>7} {'smoothness':>11} {'flips':>6}")
    for key, mean, worst, smooth, flips in rows:
        print(f"{key:26} {mean:17.2f}% {worst:6.2f}% {smooth:11.1f} {flips:6d}")


# %% [markdown]
# ### Character (figure 3)
# The right arm waves and the left leg kicks out; head, pelvis, the other wrist and
# ankle stay.

# %%
show("character")

# %% [markdown]
# ### Flower (figure 4)
# The head is pulled sideways and down; the stem bends over.

# %%
show("flower")

# %% [markdown]
# ### Stick (figure 5)
# Handles moved onto a quarter circle: the bar curls up.

# %%
show("stick")

# %% [markdown]
# ### Horse
# The front hoof lifted forward, the head raised.

# %%
show("horse")

# %% [markdown]
# **Reading the tables.** *Difference* is the mean (and max) vertex distance to the full
# solve, in percent of the rest bounding-box diagonal. *Smoothness* is the sum, over
# interior shape-mesh edges, of the norm of the jump of the deformation gradient across
# the edge: 0 for an affine map. The paper's per-triangle MVC jumps across control edges
# (the largest number); barycentric skinning is continuous with kinks; the blended MVC
# is continuous and, at the paper's 15 iterations, as smooth as the full solve or
# smoother. Control mesh only and control mesh + MVC are about equally far from the full
# solve: the difference comes from solving on the coarse mesh, not from the skinning.

# %% [markdown]
# ## Table 1, timed
# Times belong in a benchmark, not in a notebook that the tests execute:
# `python benchmarks/table1.py --json benchmarks/results/table1-cpu-2core.json` measures
# every row in one run (preprocessing, per-frame time of (da) and (ra), their ratio,
# differences, smoothness, and libigl's ARAP on the same shape mesh with the same
# handles, targets, start and 15 iterations) and writes the figures above as PNG. Its
# last results, measured on a 2-core CPU:

# %%
results = pathlib.Path(mvcjax.__file__).resolve().parents[1] / "benchmarks" / "results"
table = results / "table1-cpu-2core.json"
if table.exists():
    data = json.loads(table.read_text())
    print({k: data["meta"][k] for k in ("jax", "device", "cpu_count", "libigl", "repeats")})
    print(f"{'model':10} {'V_S':>6} {'V_C':>4} {'(da) ms':>8} {'(ra) ms':>8} {'ratio':>6} "
          f"{'ARAP ms':>8} {'(da)-(ra)':>9}")
    for r in data["rows"]:
        print(f"{r['model']:10} {r['V_S']:6d} {r['V_CP'] + r['V_CG']:4d} {r['da_frame_ms']:8.3f} "
              f"{r['ra_frame_ms']:8.2f} {r['ratio']:6.0f} "
              f"{r.get('arap_frame_ms', float('nan')):8.2f} "
              f"{r['da_difference_mean_pct']:8.2f}%")
else:
    print("No benchmark results next to this checkout: run benchmarks/table1.py.")
