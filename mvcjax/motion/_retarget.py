"""Retargeting as AnimatedDrawings does it: the clip stood up and turned to face +x at
every frame, each body-part group projected onto its plane (frontal, sagittal, or the
one PCA picks), each character bone turned to its projected bone's angle, the root moved
by the clip's root scaled by leg length, and the body parts' draw order from the depth
of their drivers."""

from __future__ import annotations

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float
from scipy.spatial.transform import Rotation

from ..geometry import pixels_to_points
from ._bvh import Motion
from ._configs import CharacterConfig, ConfigError, MotionConfig, RetargetConfig

_FRONTAL, _SAGITTAL = 0, 2  # the projection plane's normal: the x axis, the z axis


@dataclasses.dataclass(frozen=True)
class Retargeted:
    """A clip retargeted onto a character, every frame.

    Attributes:
        angles: `(frames, k)` each mapped joint's bone angle, radians counter-clockwise
            from +y, in `RetargetConfig.mapping`'s order (`joints` is their function).
        root: `(frames, 2)` the root's offset from rest.
        depths: `(frames, parts)` each body part's depth (larger: nearer the viewer).
        frame_time: seconds between frames.
        parts: the body parts' character joints, in `depths`' order.
    """

    character: CharacterConfig
    mapped: tuple[str, ...]
    angles: np.ndarray
    root: np.ndarray
    depths: np.ndarray
    frame_time: float
    parts: tuple[tuple[str, ...], ...]

    def joints(self, angles: Float[ArrayLike, "*frames k"] | None = None,
               root: Float[ArrayLike, "*frames 2"] | None = None) -> Float[Array, "*frames j 2"]:
        """The character's joints posed by bone angles and a root offset (default: the
        clip's), differentiable in both: AnimatedDrawings' forward kinematics."""
        angles = jnp.asarray(self.angles if angles is None else angles)
        root = jnp.asarray(self.root if root is None else root)
        return pose_joints(self.character, self.mapped, self.rest, angles, root)

    @property
    def rest(self) -> np.ndarray:
        """`(j, 2)` the character's joints at rest, in its picture's points (y up)."""
        return rest_points(self.character)

    def part_order(self) -> np.ndarray:
        """`(frames, j)` each joint's draw rank (higher on top): the parts sorted by
        depth, and inside a part its joints in order, reversed when it is behind."""
        return part_order(self.character, self.depths, self.parts)


def _standing(motion: Motion, config: MotionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clip stood up (+y), scaled and turned to face +x at its first frame; then
    each frame turned about +y to face +x and its root moved to the origin:
    `(relative (F, J, 3), root (F, 3), forward (F, 3))`, the root and the forward
    direction in the first frame's turn."""
    up = (Rotation.from_euler("YX", [-90.0, -90.0], degrees=True).as_matrix()
          if config.up == "+z" else np.eye(3))
    motion.index(config.ground, "groundplane_joint")  # named, so it must be there
    points = motion.positions @ up.T * config.scale
    points = points @ _facing_x(_forward(motion, points, config)[:1])[0].T
    forward = _forward(motion, points, config)
    root = points[:, 0]
    relative = np.einsum("fij,fkj->fki", _facing_x(forward), points - root[:, None])
    return relative, root, forward


def _forward(motion: Motion, points: np.ndarray, config: MotionConfig) -> np.ndarray:
    """`(F, 3)` the horizontal direction square to the mean of the `forward` joint
    pairs' directions (AnimatedDrawings' skeleton forward)."""
    across = np.mean([_unit(points[:, motion.index(b, "forward joint")]
                            - points[:, motion.index(a, "forward joint")])
                      for a, b in config.forward], axis=0)
    return _unit(np.stack([across[:, 2], np.zeros(len(across)), -across[:, 0]], -1))


def _facing_x(forward: np.ndarray) -> np.ndarray:
    """`(F, 3, 3)` the turns about +y that take each horizontal `forward` to +x."""
    angle = np.arctan2(forward[:, 2], forward[:, 0])
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1),
                     np.stack([-s, zero, c], -1)], -2)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _normals(motion: Motion, relative: np.ndarray, config: RetargetConfig) -> dict[str, int]:
    """Each projection group's plane normal axis (`_FRONTAL` or `_SAGITTAL`); `pca` picks
    the one nearer the group's least spread direction."""
    normals = {}
    for name, method, joints in config.projections:
        if method == "pca":
            points = relative[:, [motion.index(j, "joint") for j in joints]].reshape(-1, 3)
            least = np.linalg.svd(points - points.mean(0), full_matrices=False)[2][2]
            normals[name] = _FRONTAL if abs(least[0]) > abs(least[2]) else _SAGITTAL
        else:
            normals[name] = _FRONTAL if method == "frontal" else _SAGITTAL
    return normals


def _projected(bone: np.ndarray, normal: int) -> np.ndarray:
    """A 3D vector's picture-plane `(x, y)` on the plane with that normal."""
    return (np.stack([-bone[..., 2], bone[..., 1]], -1) if normal == _FRONTAL
            else bone[..., :2])


def _bone_angles(motion, relative, joint_normal, config: RetargetConfig, mapped) -> np.ndarray:
    """`(F, k)` each mapped bone's projected angle, counter-clockwise from +y."""
    angles = []
    for name in mapped:
        _, near, far = next(m for m in config.mapping if m[0] == name)
        if far not in joint_normal:
            raise ConfigError(f"{config.path}: {name} follows {far}, which no "
                              f"bvh_projection_bodypart_groups lists; add it to one.")
        bone = relative[:, motion.index(far, "joint")] - relative[:, motion.index(near, "joint")]
        x, y = np.moveaxis(_projected(bone, joint_normal[far]), -1, 0)
        angles.append(np.arctan2(y, x) - np.pi / 2)
    return np.stack(angles, -1)


def _chain_length(points: np.ndarray, chains) -> float:
    return float(sum(np.linalg.norm(points[b] - points[a])
                     for chain in chains for a, b in itertools.pairwise(chain)))


def _root_path(root, forward, normal, scale) -> np.ndarray:
    """`(F, 2)` the character's root offset: the clip root's steps, scaled, along the
    forward (sagittal) or sideways (frontal) direction, and up."""
    side = forward if normal == _SAGITTAL else forward[:, ::-1] * np.array([-1, 1, -1])
    step = np.diff(root, axis=0)
    moves = np.stack([np.sum(side[1:] * step, -1), step[:, 1]], -1) * scale
    return np.concatenate([np.zeros((1, 2)), np.cumsum(moves, 0)])


def rest_points(character: CharacterConfig) -> np.ndarray:
    """`(j, 2)` the character's joints in its picture's points (y up)."""
    return pixels_to_points(character.pixels[:, ::-1], character.size[0])


def _kept_mappings(character: CharacterConfig, rest, config: RetargetConfig) -> tuple[str, ...]:
    """The mapped character joints, less those its runtime checks drop ("above": a
    joint drawn below the line between two others, a head below its shoulders, is not
    turned)."""
    names = character.names
    mapped = [m[0] for m in config.mapping]
    for test, target, first, second in config.checks:
        if test != "above":
            raise ConfigError(f"{config.path}: char_runtime_checks test {test!r} is not "
                              f"known; AnimatedDrawings knows 'above'.")
        a, b, t = (rest[_char_index(character, n, config)] for n in (first, second, target))
        line, point = b - a, t - a
        angle = np.arctan2(line[1], line[0])
        if np.sin(-angle) * point[0] + np.cos(-angle) * point[1] < 0 and target in mapped:
            mapped.remove(target)
    for name in mapped:
        _char_index(character, name, config)
    return tuple(n for n in names if n in mapped)


def _char_index(character: CharacterConfig, name: str, config: RetargetConfig) -> int:
    if name not in character.names:
        raise ConfigError(f"{config.path}: names character joint {name!r}, which "
                          f"{character.path} does not have (its joints: "
                          f"{', '.join(character.names)}); rename it.")
    return character.names.index(name)


def retarget(character: CharacterConfig, motion: Motion, motion_config: MotionConfig,
             config: RetargetConfig) -> Retargeted:
    """The clip `motion` retargeted onto `character`, as AnimatedDrawings does."""
    relative, root, forward = _standing(motion, motion_config)
    normals = _normals(motion, relative, config)
    joint_normal = {j: normals[name] for name, _, joints in config.projections for j in joints}
    rest = rest_points(character)
    mapped = _kept_mappings(character, rest, config)
    if config.offset_group not in normals:
        raise ConfigError(f"{config.path}: bvh_projection_bodypart_group_for_offset names "
                          f"{config.offset_group!r}, not one of its groups "
                          f"{sorted(normals)}.")
    char_index = [[_char_index(character, n, config) for n in c] for c in config.offset_char]
    bvh_index = [[motion.index(n, "joint") for n in c] for c in config.offset_bvh]
    scale = (_chain_length(rest, char_index)
             / _chain_length(motion.positions[-1] * motion_config.scale, bvh_index))
    for joints, _ in config.parts:
        for name in joints:
            _char_index(character, name, config)
    return Retargeted(character=character, mapped=mapped,
                      angles=_bone_angles(motion, relative, joint_normal, config, mapped),
                      root=_root_path(root, forward, normals[config.offset_group], scale),
                      depths=_depths(motion, relative, joint_normal, config),
                      frame_time=motion_config.frame_time or motion.frame_time,
                      parts=tuple(joints for joints, _ in config.parts))


def _depths(motion, relative, joint_normal, config: RetargetConfig) -> np.ndarray:
    """`(F, parts)` each body part's depth: its drivers' mean distance to their
    projection plane."""
    columns = []
    for _, drivers in config.parts:
        for name in drivers:
            if name not in joint_normal:
                raise ConfigError(f"{config.path}: depth driver {name!r} is in no "
                                  f"bvh_projection_bodypart_groups; add it to one.")
        columns.append(np.mean([relative[:, motion.index(d, "depth driver"), joint_normal[d]]
                                for d in drivers], 0))
    return np.stack(columns, -1)


def pose_joints(character: CharacterConfig, mapped, rest, angles, root):
    """AnimatedDrawings' forward kinematics: a mapped joint's bone turns to its angle by
    turning its parent (relative to the parent's own turn when the parent is mapped
    too), and every joint below a turned joint turns with it."""
    names, parents = character.names, character.parents
    start = np.arctan2(*(rest - rest[np.maximum(parents, 0)])[:, ::-1].T) - np.pi / 2
    local = [jnp.zeros(angles.shape[:-1], angles.dtype) for _ in names]
    current: dict[int, Array] = {}
    order = _depth_first(parents)
    for j in order:
        if names[j] in mapped:
            theta = angles[..., mapped.index(names[j])] - start[j]
            current[j] = theta
            p = parents[j]
            local[p] = theta - current[p] if p in current else theta
    turn: list = [None] * len(names)
    place: list = [None] * len(names)
    for j in order:
        p = parents[j]
        if p < 0:
            turn[j] = local[j]
            place[j] = jnp.asarray(rest[j], angles.dtype) + root
            continue
        c, s = jnp.cos(turn[p])[..., None], jnp.sin(turn[p])[..., None]
        x, y = rest[j] - rest[p]
        place[j] = place[p] + jnp.concatenate([c * x - s * y, s * x + c * y], -1)
        turn[j] = turn[p] + local[j]
    return jnp.stack(place, -2)


def _depth_first(parents) -> list[int]:
    """Joint indices, each before its children, children in file order."""
    order, stack = [], [int(np.flatnonzero(np.asarray(parents) < 0)[0])]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed([c for c, p in enumerate(parents) if p == j]))
    return order


def part_order(character: CharacterConfig, depths: np.ndarray, parts) -> np.ndarray:
    """`(F, j)` each joint's draw rank: parts drawn deepest first (AnimatedDrawings'
    order), a part's joints in its listed order, or reversed when it is behind the
    plane; joints of no part rank 0."""
    ranks = np.zeros((len(depths), len(character.names)), np.int32)
    for f, frame in enumerate(depths):
        rank = 1
        for p in np.argsort(frame, kind="stable"):
            joints = parts[p] if frame[p] > 0 else parts[p][::-1]
            for name in joints:
                ranks[f, character.names.index(name)] = rank
                rank += 1
    return ranks
