"""An AnimatedDrawings character rigged by mvcjax: its mask traced to a shape, a `Bone`
per skeleton bone, each shape triangle given to the bone nearest it inside the shape
(the body part whose draw order it follows)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float
from scipy import ndimage

from ..geometry import Shape, barycentric_coordinates, load_image, locate_points
from ..rendering import depth_from_handles
from ..rig import Bone, Rig
from ._configs import CharacterConfig, ConfigError
from ._retarget import rest_points


class Drawing(eqx.Module):
    """A drawn character (AnimatedDrawings' `char_cfg.yaml`, `mask.png`, `texture.png`)
    as a rig posed by its skeleton.

    Attributes:
        config: the character's files and skeleton.
        rig: the `Rig` of its mask's shape, a `Bone` per skeleton bone of non-zero length
            (parent to child), in `bones`' order.
        bones: `(b, 2)` each bone's parent and child joint.
        vertex_joint: `(n,)` the joint whose bone is nearest each shape-mesh vertex along
            the mesh (the child joint, which names the bone, as AnimatedDrawings does).
        picture: `(rows, cols, 4)` the texture, its alpha the mask.
    """

    config: CharacterConfig = eqx.field(static=True)
    rig: Rig
    bones: np.ndarray
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
        bones = np.array([(p, j) for j, p in enumerate(config.parents)
                          if p >= 0 and np.hypot(*(rest[j] - rest[p])) > 0.5], int)
        rig = Rig.build(Shape.from_image(mask), [Bone(rest[p], rest[j]) for p, j in bones],
                        **build)
        nearest = np.asarray(depth_from_handles(rig, np.repeat(np.arange(len(bones)), 2)))
        picture = load_image(config.texture)
        if picture.shape[:2] != mask.shape:
            raise ConfigError(f"{config.texture}: {picture.shape[1]}x{picture.shape[0]} "
                              f"pixels, but {config.mask} is {mask.shape[1]}x"
                              f"{mask.shape[0]}; the texture and the mask must match.")
        picture = np.concatenate([picture[..., :3], mask[..., None].astype(picture.dtype)], -1)
        return cls(config=config, rig=rig, bones=bones,
                   vertex_joint=bones[np.rint(nearest).astype(int), 1], picture=picture)

    def targets(self, joints: Float[ArrayLike, "*frames j 2"]) -> Float[Array, "*frames h 2"]:
        """The rig's targets (each bone's start, then its end) from the joints' places."""
        return jnp.asarray(joints)[..., self.bones.reshape(-1), :]

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
