"""Figures: meshes, rigs and deformations (matplotlib)."""

from __future__ import annotations

import numpy as np

from .geometry import boundary_loops


def _axes(ax):
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6, 5))
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    return ax


def plot_mesh(vertices, faces, ax=None, *, color="0.55", linewidth=0.3, **kwargs):
    """Draw a triangle mesh's edges; extra keywords go to `Axes.triplot`."""
    ax = _axes(ax)
    v, f = np.asarray(vertices), np.asarray(faces)
    ax.triplot(v[:, 0], v[:, 1], f, color=color, linewidth=linewidth, **kwargs)
    return ax


def plot_outline(rig, ax=None, vertices=None, **kwargs):
    """The outline (every boundary loop) of the shape mesh, at rest or at `vertices`;
    keywords go to `Axes.plot`."""
    ax = _axes(ax)
    v = np.asarray(rig.shape_mesh.vertices if vertices is None else vertices)
    kwargs = {"color": "0.3", "linewidth": 0.8, **kwargs}
    for loop in boundary_loops(np.asarray(rig.shape_mesh.faces)):
        closed = np.append(loop, loop[0])
        ax.plot(v[closed, 0], v[closed, 1], **kwargs)
    return ax


def _draw_handles(ax, rig, pinned, targets):
    """Pinned vertices as red dots, bones as red segments through them, targets as
    crosses (a bone's two targets joined by a dashed line)."""
    # Rows that pin nothing (spare pins, pins taken out) are not drawn.
    pins, active = np.asarray(rig.handles.row_active()), np.asarray(rig.handles.active)
    first = np.asarray(rig.handles.first)[pins]
    pinned = pinned[pins]
    bones = [bone for bone in np.asarray(rig.handles.bones) if active[bone[0]]]
    ax.plot(pinned[:, 0], pinned[:, 1], "o", color="tab:red", markersize=5, label="handles")
    for start, _ in bones:
        on = pinned[first == start]
        ax.plot(on[:, 0], on[:, 1], "-", color="tab:red", linewidth=3, solid_capstyle="round")
    if targets is not None:
        t = np.asarray(targets)
        ax.plot(t[active, 0], t[active, 1], "x", color="k", markersize=7, label="targets")
        for bone in bones:
            ax.plot(t[bone, 0], t[bone, 1], "--", color="k", linewidth=0.8)


def plot_rig(rig, ax=None, *, control_vertices=None, shape_vertices=None, targets=None):
    """The shape mesh under the control mesh, polygon `V_CP` and handles marked.

    Pass deformed `control_vertices` / `shape_vertices` (and `targets`) to draw a pose.
    """
    ax = _axes(ax)
    sv = rig.shape_mesh.vertices if shape_vertices is None else shape_vertices
    cv = rig.control_mesh.vertices if control_vertices is None else control_vertices
    sv, cv = np.asarray(sv), np.asarray(cv)
    plot_mesh(sv, rig.shape_mesh.faces, ax, color="0.6", linewidth=0.25)
    plot_mesh(cv, rig.control_mesh.faces, ax, color="tab:blue", linewidth=0.7)
    outer = np.asarray(rig.control_mesh.outer)
    ax.plot(cv[outer, 0], cv[outer, 1], ".", color="tab:blue", markersize=3)
    _draw_handles(ax, rig, cv[np.asarray(rig.control_mesh.handles)], targets)
    return ax


def plot_deformation(rig, shape_vertices, targets=None, ax=None, *, rest=True):
    """The deformed shape mesh over the rest outline, with handles and targets."""
    ax = _axes(ax)
    if rest:
        plot_mesh(rig.shape_mesh.vertices, rig.shape_mesh.faces, ax, color="0.85", linewidth=0.25)
    plot_mesh(shape_vertices, rig.shape_mesh.faces, ax, color="tab:green", linewidth=0.3)
    sv = np.asarray(shape_vertices)
    _draw_handles(ax, rig, sv[np.asarray(rig.shape_mesh.handles)], targets)
    return ax


def plot_folds(rig, shape_vertices, ax=None, *, color="tab:red", alpha=0.8):
    """Fill the shape-mesh triangles that `shape_vertices` turned inside out (as
    `mvcjax.flipped_triangles` counts them); returns how many there are."""
    from matplotlib.collections import PolyCollection

    ax = _axes(ax)
    rest, faces = np.asarray(rig.shape_mesh.vertices, np.float64), np.asarray(rig.shape_mesh.faces)
    v = np.asarray(shape_vertices, np.float64)

    def signed(points):
        a, b, c = (points[faces[:, k]] for k in range(3))
        return (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]

    folded = np.flatnonzero(np.sign(signed(v)) != np.sign(signed(rest)))
    if len(folded):
        ax.add_collection(PolyCollection(v[faces[folded]], facecolors=color, edgecolors=color,
                                         linewidths=0.6, alpha=alpha, zorder=5))
    return len(folded)


def plot_comparison(rig, panels, targets=None, *, size=3.6):
    """A row of panels like the paper's figures 3 to 5: the input with both meshes, then
    one deformed shape mesh per entry of `panels` (`{title: (n, 2) vertices}`).

    Returns the matplotlib figure.
    """
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 1 + len(panels), figsize=(size * (1 + len(panels)), size))
    plot_rig(rig, axes[0])
    axes[0].set_title("(ga) input, shape and control meshes", fontsize=9)
    for ax, (title, vertices) in zip(axes[1:], panels.items()):
        plot_deformation(rig, vertices, targets, ax)
        ax.set_title(title, fontsize=9)
    # One frame for all panels, so that the poses compare at a glance.
    points = np.concatenate([np.asarray(rig.control_mesh.vertices),
                             *(np.asarray(v) for v in panels.values())])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = 0.03 * (hi - lo).max()
    for ax in axes:
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    fig.tight_layout()
    return fig
