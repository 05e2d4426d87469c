"""Topology of a triangle mesh, from its faces alone: edges, boundary loops, neighbours
across edges and the star of every vertex.

Everything is vectorised numpy (sorting integer keys), so that large meshes cost
little; faces are `(f, 3)` vertex indices, counter-clockwise.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Int


def _half_edges(faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every face's directed edges `u -> v` (ab, bc, ca) and the third vertex of each."""
    faces = np.asarray(faces, np.int64)
    u = faces.reshape(-1)
    v = np.roll(faces, -1, axis=1).reshape(-1)
    third = np.roll(faces, -2, axis=1).reshape(-1)
    return u, v, third


def _find(keys: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Where each query sits in `keys` (unique integers), -1 where it is absent."""
    if len(keys) == 0:
        return np.full(len(queries), -1)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    at = np.clip(np.searchsorted(sorted_keys, queries), 0, len(keys) - 1)
    return np.where(sorted_keys[at] == queries, order[at], -1)


def _twins(faces) -> np.ndarray:
    """For each half-edge `u -> v`, the index of the half-edge `v -> u`, or -1 on the boundary."""
    u, v, _ = _half_edges(faces)
    n = int(max(u.max(initial=-1), v.max(initial=-1))) + 1
    return _find(u * n + v, v * n + u)


def edges(faces: Int[np.ndarray, "f 3"]) -> Int[np.ndarray, "e 2"]:
    """Every undirected edge once, as sorted vertex pairs in lexicographic order."""
    u, v, _ = _half_edges(faces)
    return np.unique(np.stack([np.minimum(u, v), np.maximum(u, v)], axis=1), axis=0)


def boundary_edges(faces: Int[np.ndarray, "f 3"]) -> Int[np.ndarray, "b 2"]:
    """The directed edges with a face on one side only, oriented as that face."""
    u, v, _ = _half_edges(faces)
    alone = on_boundary(faces).reshape(-1)
    return np.stack([u[alone], v[alone]], axis=1)


def on_boundary(faces: Int[np.ndarray, "f 3"]) -> Bool[np.ndarray, "f 3"]:
    """Whether each face's edges ab, bc, ca have no face on their other side."""
    return (_twins(faces) < 0).reshape(-1, 3)


def interior_edges(faces: Int[np.ndarray, "f 3"], loops=None) -> Int[np.ndarray, "e 2"]:
    """The undirected edges on none of `loops` (vertex index arrays, each a closed loop),
    as sorted vertex pairs; by default the loops are the mesh's boundary."""
    all_edges = edges(faces)
    if loops is None:
        on_loop = boundary_edges(faces)
    elif len(loops):
        on_loop = np.concatenate([np.stack([lp, np.roll(lp, -1)], axis=1) for lp in loops])
    else:
        on_loop = np.zeros((0, 2), np.int64)
    n = int(all_edges.max(initial=-1)) + 1
    key = np.minimum(on_loop[:, 0], on_loop[:, 1]) * n + np.maximum(on_loop[:, 0], on_loop[:, 1])
    return all_edges[~np.isin(all_edges[:, 0] * n + all_edges[:, 1], key)]


def face_pairs(faces: Int[np.ndarray, "f 3"]) -> Int[np.ndarray, "e 2"]:
    """Pairs of faces that share an edge, each pair once."""
    twins = _twins(faces)
    mine = np.flatnonzero(twins > np.arange(len(twins)))
    return np.stack([mine // 3, twins[mine] // 3], axis=1)


def face_neighbours(faces: Int[np.ndarray, "f 3"]) -> Int[np.ndarray, "f 3"]:
    """For face `(a, b, c)`, the vertex opposite across edges ab, bc, ca (-1 if none)."""
    _, _, third = _half_edges(faces)
    twins = _twins(faces)
    return np.where(twins >= 0, third[twins], -1).reshape(-1, 3)


def face_star_polygons(
    faces: Int[np.ndarray, "f 3"], neighbours: Int[np.ndarray, "f 3"]
) -> tuple[Int[np.ndarray, "f 6"], Bool[np.ndarray, "f 6"]]:
    """Eq. 1's polygon of each face: `a, x_ab, b, x_bc, c, x_ca`, missing neighbours skipped.

    Returns vertex indices `(f, 6)`, compacted to the front, and which are valid.
    """
    poly = np.stack(
        [faces[:, 0], neighbours[:, 0], faces[:, 1], neighbours[:, 1],
         faces[:, 2], neighbours[:, 2]],
        axis=1,
    )
    valid = poly >= 0
    order = np.argsort(~valid, axis=1, kind="stable")
    poly = np.take_along_axis(poly, order, axis=1)
    valid = np.take_along_axis(valid, order, axis=1)
    return np.where(valid, poly, 0), valid


def boundary_loops(faces: Int[np.ndarray, "f 3"]) -> list[Int[np.ndarray, " k"]]:
    """Boundary loops of a triangle mesh, oriented as its faces (the outer loop
    counter-clockwise, holes clockwise, for counter-clockwise faces)."""
    boundary = boundary_edges(faces)
    if len(boundary) == 0:
        return []
    if len(np.unique(boundary[:, 0])) != len(boundary):
        vertex = int(np.bincount(boundary[:, 0]).argmax())
        raise ValueError(
            f"the mesh's boundary passes twice through vertex {vertex} (two boundary loops "
            "touch there, or two fans of triangles meet at a point); separate them by at "
            "least one triangle."
        )
    successor = dict(zip(boundary[:, 0].tolist(), boundary[:, 1].tolist()))
    loops = []
    while successor:
        start = next(iter(successor))
        loop = [start]
        while (nxt := successor.pop(loop[-1])) != start:
            loop.append(nxt)
        loops.append(np.asarray(loop, np.int64))
    return loops


def _chain_positions(successor: np.ndarray) -> np.ndarray:
    """For disjoint chains given by `successor` (-1 at each end), how many steps each
    element is from the end of its chain (pointer jumping: log2 of the longest chain)."""
    steps = (successor >= 0).astype(np.int64)
    jump = successor.copy()
    while np.any(jump >= 0):
        live = jump >= 0
        steps[live] += steps[jump[live]]
        jump = np.where(live, jump[np.where(live, jump, 0)], -1)
    return steps


def vertex_stars(
    faces: Int[np.ndarray, "f 3"], count: int
) -> tuple[Int[np.ndarray, "count k"], Bool[np.ndarray, "count k"]]:
    """The star polygon of every vertex, counter-clockwise, padded.

    An interior vertex's star is its ordered 1-ring; a boundary vertex's is the vertex
    itself followed by its fan of neighbours (the polygon of the triangles around it).
    A vertex in no face gets an empty star.

    Returns vertex indices `(count, k)` and which are valid `(count, k)`.
    """
    faces = np.asarray(faces, np.int64)
    # Corner (v, b, c) of a face: around v, the fan steps from neighbour b to neighbour c.
    v, b, c = _half_edges(faces)
    corners = len(v)
    n = max(count, int(faces.max(initial=-1)) + 1)
    nxt = _find(v * n + b, v * n + c)  # the corner at v whose b is this corner's c
    has_prev = np.zeros(corners, bool)
    has_prev[nxt[nxt >= 0]] = True
    starts = np.flatnonzero(~has_prev)
    if len(np.unique(v[starts])) != len(starts):
        vertex = int(np.bincount(v[starts]).argmax())
        raise ValueError(
            f"vertex {vertex} of the mesh has two separate fans of triangles (the mesh "
            "pinches there); make the mesh manifold, e.g. by separating the fans."
        )
    degree = np.bincount(v, minlength=count)
    on_boundary = np.zeros(count, bool)
    on_boundary[v[starts]] = True
    # Interior fans are cycles: cut each at its vertex's first corner.
    first = np.full(count, corners)
    np.minimum.at(first, v, np.arange(corners))
    cut = (nxt >= 0) & ~on_boundary[v] & (nxt == first[v])
    nxt = np.where(cut, -1, nxt)
    position = degree[v] - 1 - _chain_positions(nxt)
    shift = on_boundary[v].astype(np.int64)  # a boundary star starts with the vertex itself
    width = int((degree + on_boundary * 2).max(initial=1))
    idx = np.zeros((count, width), np.int64)
    valid = np.zeros((count, width), bool)
    idx[v, position + shift] = b
    valid[v, position + shift] = True
    ends = np.flatnonzero((nxt < 0) & on_boundary[v])
    idx[v[ends], position[ends] + 2] = c[ends]
    valid[v[ends], position[ends] + 2] = True
    rims = np.flatnonzero(on_boundary)
    idx[rims, 0] = rims
    valid[rims, 0] = True
    return idx, valid
