"""Measures of a deformation: difference between two results, smoothness, flips."""

from __future__ import annotations

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from ._coordinates import signed_areas
from ._topology import face_pairs


def difference(
    a: Float[ArrayLike, "n 2"], b: Float[ArrayLike, "n 2"], rest: Float[ArrayLike, "n 2"]
) -> tuple[float, float]:
    """Mean and max vertex distance between two deformed meshes, in percent of the rest
    bounding-box diagonal."""
    a, b, rest = (np.asarray(x, np.float64) for x in (a, b, rest))
    diagonal = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    d = np.linalg.norm(a - b, axis=1) / diagonal * 100.0
    return float(d.mean()), float(d.max())


def deformation_gradients(
    rest: Float[ArrayLike, "n 2"],
    deformed: Float[ArrayLike, "n 2"],
    faces: Int[ArrayLike, "f 3"],
) -> Float[np.ndarray, "f 2 2"]:
    """The constant deformation gradient of each triangle (rest -> deformed)."""
    rest, deformed = np.asarray(rest, np.float64), np.asarray(deformed, np.float64)
    faces = np.asarray(faces)

    def edges(v):
        return np.stack([v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]], axis=2)

    return edges(deformed) @ np.linalg.inv(edges(rest))


def smoothness(
    rest: Float[ArrayLike, "n 2"],
    deformed: Float[ArrayLike, "n 2"],
    faces: Int[ArrayLike, "f 3"],
) -> float:
    """Sum over interior edges of the jump of the deformation gradient across the edge
    (Frobenius norm): 0 for an affine map, small for a smooth deformation, large where
    the skinning has kinks or tears along control edges."""
    grads = deformation_gradients(rest, deformed, faces)
    pairs = face_pairs(np.asarray(faces))
    jump = grads[pairs[:, 0]] - grads[pairs[:, 1]]
    return float(np.linalg.norm(jump, axis=(1, 2)).sum())


def flipped_triangles(
    rest: Float[ArrayLike, "n 2"],
    deformed: Float[ArrayLike, "*frames n 2"],
    faces: Int[ArrayLike, "f 3"],
) -> int | Int[np.ndarray, "*frames"]:
    """How many triangles changed orientation: an int for one pose `(n, 2)`, an array of
    counts for poses `(*frames, n, 2)`."""
    faces = np.asarray(faces)

    def signs(v):
        return np.sign(signed_areas(np.asarray(v, np.float64), faces))

    counts = np.sum(signs(rest) != signs(deformed), axis=-1)
    return int(counts) if counts.ndim == 0 else counts
