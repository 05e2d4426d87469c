"""An AnimatedDrawings character rigged by mvcjax: its mask traced to a shape, a `Bone`
per skeleton bone, each shape triangle given to the bone nearest it inside the shape
(the body part whose draw order it follows)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import shapely
from jaxtyping import Array, ArrayLike, Float
from scipy import ndimage

from ..geometry import Shape, barycentric_coordinates, load_image, locate_points
from ..rendering import spread_from_handles
from ..rig import Bone, Rig
from ._configs import CharacterConfig, ConfigError
from ._retarget import rest_points


class Drawing(eqx.Module):
    """A drawn character (AnimatedDrawings' `char_cfg.yaml`, `mask.png`, `texture.png`)
    as a rig posed by its skeleton.

    Attributes:
        config: the character's files and skeleton.
        rig: the `Rig` of its mask's shape: a `Bone` per skeleton bone (parent to child)
            that lies inside the shape; a bone that leaves it (a straight bone along a
            curved, thin arm) is pinned at its ends instead, where they lie inside, as
            AnimatedDrawings pins joints.
        rows: `(r,)` the joint each row of the rig's targets follows.
        vertex_joint: `(n,)` the joint whose bone is nearest each shape-mesh vertex along
            the mesh (the child joint, which names the bone, as AnimatedDrawings does).
        picture: `(rows, cols, 4)` the texture, its alpha the mask.
    """

    config: CharacterConfig = eqx.field(static=True)
    rig: Rig
    rows: np.ndarray
    vertex_joint: np.ndarray
    picture: np.ndarray

    @classmethod
    def load(cls, character: Any, **build: Any) -> Drawing:
        """Read a character (its folder or its `char_cfg.yaml`) and rig it.

        Args:
            character: the folder holding `char_cfg.yaml`, `mask.png` and `texture.png`,
                or the `char_cfg.yaml`.
            **build: options of `Rig.build` (`shape_spacing`, `control`, `dtype`, ...).

        Refused with an error naming the file: a mask with several separate blobs, and
        joints outside the mask.
        """
        config = character if isinstance(character, CharacterConfig) else \
            CharacterConfig.read(character)
        mask = _mask(config)
        rest = rest_points(config)
        _check_joints_on_mask(config, mask)
        shape = Shape.from_image(mask)
        handles, rows, owners = _handles(shape, rest, config.parents)
        rig = Rig.build(shape, handles, **build)
        nearest, _ = spread_from_handles(rig, owners, "owners")
        picture = load_image(config.texture)
        if picture.shape[:2] != mask.shape:
            raise ConfigError(f"{config.texture}: {picture.shape[1]}x{picture.shape[0]} "
                              f"pixels, but {config.mask} is {mask.shape[1]}x"
                              f"{mask.shape[0]}; the texture and the mask must match.")
        picture = np.concatenate([picture[..., :3], mask[..., None].astype(picture.dtype)], -1)
        return cls(config=config, rig=rig, rows=rows,
                   vertex_joint=np.rint(nearest).astype(int), picture=picture)

    def targets(self, joints: Float[ArrayLike, "*frames j 2"]) -> Float[Array, "*frames h 2"]:
        """The rig's targets (a bone's start, then its end; a point's joint) from the
        joints' places."""
        return jnp.asarray(joints)[..., self.rows, :]

    def face_joints(self, faces: Any) -> np.ndarray:
        """`(f,)` the joint each triangle follows in draw order: most of its vertices'."""
        joints = self.vertex_joint[np.asarray(faces)]
        agree = joints[:, 1] == joints[:, 2]
        return np.where(agree, joints[:, 1], joints[:, 0])

    def joints_on(self, vertices: Float[ArrayLike, "*frames n 2"]) -> np.ndarray:
        """`(*frames, j, 2)` where the deformed shape carries each joint of the rest
        picture (its triangle's barycentric coordinates, kept)."""
        mesh = self.rig.shape_mesh
        rest_vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        rest = rest_points(self.config)
        face, _ = locate_points(rest, rest_vertices, faces)
        weights = barycentric_coordinates(rest, rest_vertices[faces[face]])
        corners = np.asarray(vertices)[..., faces[face], :]
        return np.einsum("...jkd,jk->...jd", corners, weights)


def _handles(shape: Shape, rest: np.ndarray, parents) -> tuple[list, np.ndarray, np.ndarray]:
    """The rig's handles, the joint each target row follows, and each row's bone (its
    child joint, which names it)."""
    inside = shape.polygon.buffer(1e-6 * shape.diagonal)
    handles, rows, owners, ends, loose = [], [], [], set(), []
    for j, p in enumerate(parents):
        if p < 0 or np.hypot(*(rest[j] - rest[p])) <= 0.5:
            continue
        if inside.covers(shapely.LineString([rest[p], rest[j]])):
            handles.append(Bone(rest[p], rest[j]))
            rows += [p, j]
            owners += [j, j]
            ends.update(_place(rest, (p, j)))
        else:
            loose += [(p, j), (j, j)]
    for joint, owner in loose:
        place = _place(rest, (joint,))[0]
        if place not in ends and inside.covers(shapely.Point(rest[joint])):
            handles.append(rest[joint])
            rows.append(joint)
            owners.append(owner)
            ends.add(place)
    return handles, np.array(rows, int), np.array(owners, float)


def _place(rest: np.ndarray, joints) -> list[tuple[float, float]]:
    return [tuple(np.round(rest[j], 6)) for j in joints]


def _mask(config: CharacterConfig) -> np.ndarray:
    """The character's mask as booleans, refused if it holds several blobs."""
    picture = load_image(config.mask)
    mask = picture[..., :3].mean(-1) * picture[..., 3] > 0.5
    if mask.shape != config.size:
        raise ConfigError(f"{config.mask}: {mask.shape[1]}x{mask.shape[0]} pixels, but "
                          f"{config.path} says width {config.size[1]}, height "
                          f"{config.size[0]}; fix the height and width there.")
    labels, count = ndimage.label(mask)
    if count != 1:
        sizes = np.bincount(labels.ravel())[1:]
        raise ConfigError(f"{config.mask}: the mask holds {count} separate blobs (of "
                          f"{', '.join(map(str, sorted(sizes, reverse=True)[:5]))} pixels); "
                          f"a character is one piece: join them or erase the strays.")
    return mask


def _check_joints_on_mask(config: CharacterConfig, mask: np.ndarray,
                          reach: float = 0.05) -> None:
    """Joints must lie on the mask, or within `reach` of the picture's size of it (a
    hand drawn at a finger's tip)."""
    distance = ndimage.distance_transform_edt(~mask)
    rows, cols = np.clip(np.rint(config.pixels[:, ::-1]).astype(int), 0,
                         np.array(mask.shape) - 1).T
    far = distance[rows, cols] > reach * max(mask.shape)
    if far.any():
        names = [n for n, f in zip(config.names, far) if f]
        raise ConfigError(f"{config.path}: joints {names} lie outside {config.mask} (more "
                          f"than {reach:.0%} of the picture away); move their loc onto "
                          f"the character.")
