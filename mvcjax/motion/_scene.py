"""A scene of drawn characters, each driven by its motion capture clip: targets, poses
and pictures of every frame, and the animation file."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from .._animation import deform_frames
from ..core import whole_number
from ..export import write_animation, write_image
from ..geometry import flipped_triangles
from ..rendering import Renderer, fit_window
from ._bvh import read_bvh
from ._configs import CharacterConfig, MotionConfig, RetargetConfig, SceneEntry, read_scene
from ._drawing import Drawing
from ._retarget import Retargeted, retarget

_MAX_SIDE = 1024


@dataclasses.dataclass(frozen=True)
class PoseReport:
    """Per frame: how far the posed picture carries each joint from where the clip puts
    it (the largest, in the picture's pixels), and how many shape triangles fold."""

    joint_miss: np.ndarray
    flipped: np.ndarray

    @property
    def folded_frames(self) -> float:
        """The fraction of frames with a fold."""
        return float(np.mean(self.flipped > 0))


@dataclasses.dataclass(frozen=True)
class Actor:
    """A drawing and the clip retargeted onto it."""

    drawing: Drawing
    motion: Retargeted
    start: np.ndarray  # char_starting_location: x, y in pictures' sizes, z the depth

    def targets(self, frames: int) -> np.ndarray:
        """`(frames, h, 2)` the rig's targets, the clip's last frame held past its end."""
        joints = np.asarray(self.motion.joints())
        return np.asarray(self.drawing.targets(joints[_held(np.arange(frames), joints)]))

    def levels(self, faces: Any, frames: int) -> np.ndarray:
        """`(frames, f)` each triangle's draw level: its body part's rank that frame."""
        ranks = self.motion.part_order()
        return ranks[_held(np.arange(frames), ranks)][:, self.drawing.face_joints(faces)]

    def report(self, vertices: Any, frames: Any = None) -> PoseReport:
        """How well the poses `(f, n, 2)` (`Scene.deform`'s) follow the clip: poses of its
        `frames` (`(f,)` indices; default its first `f`, the last held past its end)."""
        vertices = np.asarray(vertices)
        mesh = self.drawing.rig.shape_mesh
        joints = np.asarray(self.motion.joints())
        held = _held(np.arange(len(vertices)) if frames is None else np.asarray(frames),
                     joints)
        miss = np.linalg.norm(self.drawing.joints_on(vertices) - joints[held], axis=-1)
        return PoseReport(joint_miss=miss.max(axis=-1),
                          flipped=np.asarray(flipped_triangles(mesh.vertices, vertices,
                                                               mesh.faces)))

    def to_scene(self, vertices: Any, unit: Any) -> np.ndarray:
        """Rig coordinates (the picture's pixels) to the scene's: the rest root at the
        starting location, a picture's larger side `unit` long."""
        scale = unit / max(self.drawing.config.size)
        root = self.motion.rest[self.drawing.config.parents.index(-1)]
        return (np.asarray(vertices) - root) * scale + self.start[:2] * unit


@dataclasses.dataclass(frozen=True)
class Scene:
    """Drawn characters moved by motion capture, as AnimatedDrawings' files describe
    them: `Scene.read("scene.yaml")` or `Scene.from_files(character, motion,
    retarget)`; then `scene.write("dance.gif")`.

    Attributes:
        actors: each character with its retargeted clip, drawn back to front.
    """

    actors: tuple[Actor, ...]

    @classmethod
    def read(cls, path: Any, **build: Any) -> Scene:
        """The characters of an AnimatedDrawings scene file (an `mvc/*.yaml`), each
        rigged (`**build`: options of `Rig.build`) and retargeted."""
        return cls._of(read_scene(path), build)

    @classmethod
    def from_files(cls, character: Any, motion: Any, retarget: Any, **build: Any) -> Scene:
        """One character (its folder or `char_cfg.yaml`) with a motion config and a
        retarget config."""
        entry = SceneEntry(CharacterConfig.read(character), MotionConfig.read(motion),
                           RetargetConfig.read(retarget))
        return cls._of((entry,), build)

    @classmethod
    def _of(cls, entries, build) -> Scene:
        actors = []
        for entry in entries:
            clip = read_bvh(entry.motion.bvh, entry.motion.start, entry.motion.stop)
            # Retargeted first: a config that names a joint the character lacks is
            # refused before the drawing is read and rigged.
            motion = retarget(entry.character, clip, entry.motion, entry.retarget)
            actors.append(Actor(Drawing.load(entry.character, **build), motion,
                                entry.retarget.start))
        return cls(tuple(sorted(actors, key=lambda a: a.start[2])))

    @property
    def frames(self) -> int:
        """The number of frames: the longest clip's."""
        return max(len(a.motion.angles) for a in self.actors)

    @property
    def fps(self) -> float:
        return 1.0 / self.actors[0].motion.frame_time

    def deform(self, solver: Any = None, *, chunk: Any = None) -> tuple[np.ndarray, ...]:
        """Each character's `(frames, n, 2)` shape-mesh vertices at every frame
        (`deform_frames` with `solver`, default the rig's)."""
        options = {} if solver is None else {"solver": solver}
        return tuple(np.asarray(deform_frames(a.drawing.rig, a.targets(self.frames),
                                              chunk=chunk, **options))
                     for a in self.actors)

    def pictures(self, vertices: Any = None, *, solver: Any = None, size: Any = None,
                 follow: bool = False, progress: Any = None) -> np.ndarray:
        """`(frames, rows, cols, 4)` uint8 RGBA pictures of every frame, characters drawn
        back to front, each body part in its clip's draw order.

        Args:
            vertices: each character's poses (`deform`'s); default `deform(solver)`.
            size: the pictures' longer side in pixels (default: a pixel of the largest
                character's picture, at most 1024).
            follow: False (default): one window holds the whole animation, as a camera
                standing still (a character walking across it stays small); True: the
                window moves with the characters, their bounding box centred each frame.
            progress: a progress bar (`Renderer.frames`').
        """
        vertices = self.deform(solver) if vertices is None else vertices
        unit = float(max(max(a.drawing.config.size) for a in self.actors))
        placed = [a.to_scene(np.asarray(v), unit) for a, v in zip(self.actors, vertices)]
        if follow:
            low = np.min([p.min(axis=1) for p in placed], axis=0)
            high = np.max([p.max(axis=1) for p in placed], axis=0)
            placed = [p - 0.5 * (low + high)[:, None] for p in placed]
        window = fit_window(np.concatenate([p.reshape(-1, 2) for p in placed]))
        extent = np.array(window[2:]) - window[:2]
        longest = (min(_MAX_SIDE, int(np.ceil(extent.max()))) if size is None
                   else whole_number(size, "size", what=" of pixels"))
        shape = tuple(int(v) for v in np.maximum(np.rint(extent[::-1] / extent.max() * longest), 1))
        out = None
        for actor, poses in zip(self.actors, placed):
            rig = actor.drawing.rig
            renderer = Renderer.build(rig, actor.drawing.picture, window=window, size=shape)
            drawn = renderer.frames(poses, levels=actor.levels(renderer.faces, len(poses)),
                                    progress=progress)
            if out is None:
                out = drawn
                continue
            for frame, picture in enumerate(drawn):  # a frame at a time: little memory
                out[frame] = _over(picture, out[frame])
        return out

    def write(self, path: Any, *, vertices: Any = None, solver: Any = None, size: Any = None,
              follow: bool = False, progress: Any = None, **options: Any) -> None:
        """Write the animation: a GIF, MP4, animated PNG or WebP (`export.write_animation`
        with `**options`), or, for a path without a suffix, a folder of PNG frames.
        `vertices`, `solver`, `size`, `follow`, `progress`: as `pictures` takes them."""
        pictures = self.pictures(vertices, solver=solver, size=size, follow=follow,
                                 progress=progress)
        path = Path(os.fspath(path))
        if path.suffix:
            write_animation(path, pictures, fps=self.fps, progress=progress, **options)
            return
        path.mkdir(parents=True, exist_ok=True)
        for i, picture in enumerate(pictures):
            write_image(path / f"frame_{i:04d}.png", picture, **options)


def _held(frames: np.ndarray, clip: np.ndarray) -> np.ndarray:
    """The clip's frames shown at `frames`: its last one held past its end."""
    return np.minimum(frames, len(clip) - 1)


def _over(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Straight-alpha uint8 pictures composited, `top` over `bottom`."""
    a = top[..., 3:].astype(np.float32) / 255
    b = bottom[..., 3:].astype(np.float32) / 255
    alpha = a + b * (1 - a)
    colour = (top[..., :3] * a + bottom[..., :3] * b * (1 - a)) / np.maximum(alpha, 1e-6)
    return np.concatenate([colour, alpha * 255], -1).round().astype(np.uint8)
