"""BVH motion capture files: a skeleton of joints with offsets, Euler angle channels per
frame, read into the joints' world positions at every frame."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import equinox as eqx
import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POSITIONS = ("Xposition", "Yposition", "Zposition")


class BVHError(ValueError):
    """A BVH file that cannot be read: the message names the file, the line and the fix."""


class Motion(eqx.Module):
    """A motion capture clip: its joints and where each one is at every frame.

    Attributes:
        names: the joints' names, parents before children (an `End Site` is named after
            its joint: `"Head/End Site"`).
        parents: each joint's parent's index, -1 for the root.
        offsets: `(j, 3)` each joint's offset from its parent at rest.
        positions: `(frames, j, 3)` every joint's world position at every frame.
        frame_time: seconds between frames.
        path: the file it was read from.
    """

    names: tuple[str, ...] = eqx.field(static=True)
    parents: np.ndarray
    offsets: Float[np.ndarray, "j 3"]
    positions: Float[np.ndarray, "frames j 3"]
    frame_time: float = eqx.field(static=True)
    path: str = eqx.field(static=True)

    def index(self, name: str, what: str = "joint") -> int:
        """The index of the joint `name`, or an error naming the file and its joints."""
        if name not in self.names:
            raise BVHError(f"{self.path}: has no {what} {name!r}; its joints are "
                           f"{', '.join(self.names)}. Name one of them in the config.")
        return self.names.index(name)

    def position(self, name: str) -> np.ndarray:
        """`(frames, 3)` the joint `name`'s world positions."""
        return self.positions[:, self.index(name)]


class _Reader:
    """A BVH file's words, read one at a time, with the line each came from."""

    def __init__(self, path: Path):
        self.path = path
        self.words = [(word, number) for number, line in
                      enumerate(path.read_text(errors="replace").splitlines(), 1)
                      for word in line.split()]
        self.at = 0

    def fail(self, problem: str) -> BVHError:
        line = self.words[min(self.at, len(self.words) - 1)][1] if self.words else 1
        return BVHError(f"{self.path}, line {line}: {problem}. A BVH file lists HIERARCHY, "
                        f"then MOTION, Frames: and Frame Time: and one line of numbers per "
                        f"frame; export it again or fix it there.")

    def next(self) -> str:
        if self.at >= len(self.words):
            raise self.fail("the file ends early (truncated?)")
        self.at += 1
        return self.words[self.at - 1][0]

    def expect(self, word: str) -> None:
        found = self.next()
        if found != word:
            raise self.fail(f"expected {word!r}, found {found!r}")

    def number(self) -> float:
        word = self.next()
        try:
            return float(word)
        except ValueError:
            raise self.fail(f"expected a number, found {word!r}") from None


def _read_joint(reader: _Reader, name: str, parent: int, joints: list) -> None:
    """One joint and its children, appended to `joints` as (name, parent, offset,
    channels)."""
    reader.expect("{")
    reader.expect("OFFSET")
    offset = [reader.number() for _ in range(3)]
    channels: list[str] = []
    if reader.at < len(reader.words) and reader.words[reader.at][0] == "CHANNELS":
        reader.next()
        count = int(reader.number())
        channels = [reader.next() for _ in range(count)]
        unknown = [c for c in channels if c not in _AXES and c not in _POSITIONS]
        if unknown:
            raise reader.fail(f"joint {name!r} has unknown channels {unknown}")
    index = len(joints)
    joints.append((name, parent, offset, channels))
    while True:
        word = reader.next()
        if word == "}":
            return
        if word == "JOINT":
            _read_joint(reader, reader.next(), index, joints)
        elif word == "End":
            reader.expect("Site")
            _read_joint(reader, f"{name}/End Site", index, joints)
        else:
            raise reader.fail(f"expected JOINT, End Site or }}, found {word!r}")


def _read_frames(reader: _Reader, width: int) -> tuple[np.ndarray, float]:
    reader.expect("MOTION")
    reader.expect("Frames:")
    count = int(reader.number())
    reader.expect("Frame")
    reader.expect("Time:")
    frame_time = reader.number()
    values = reader.words[reader.at:]
    if len(values) != count * width:
        raise reader.fail(f"it says {count} frames of {width} numbers but holds "
                          f"{len(values)} numbers ({len(values) / max(width, 1):.1f} "
                          f"frames): truncated or cut mid-frame")
    try:
        frames = np.array([float(word) for word, _ in values]).reshape(count, width)
    except ValueError as error:
        raise reader.fail(f"a frame holds something other than numbers ({error})") from None
    if not np.all(np.isfinite(frames)):
        raise reader.fail("a frame holds a NaN or an infinite number")
    return frames, frame_time


def _world_positions(joints: list, frames: np.ndarray) -> np.ndarray:
    """`(frames, j, 3)` each joint's world position: a joint's frame is its parent's,
    moved by its offset (and its position channels), turned by its Euler angles
    (the channels' order, intrinsic, degrees)."""
    count = len(frames)
    turns, places = [], []
    column = 0
    for _, parent, offset, channels in joints:
        values = frames[:, column:column + len(channels)]
        column += len(channels)
        place = np.tile(np.asarray(offset, float), (count, 1))
        for axis, name_ in enumerate(_POSITIONS):
            if name_ in channels:
                place[:, axis] = values[:, channels.index(name_)]
        order = "".join(_AXES[c] for c in channels if c in _AXES)
        angles = values[:, [i for i, c in enumerate(channels) if c in _AXES]]
        turn = (Rotation.from_euler(order, angles, degrees=True).as_matrix() if order
                else np.broadcast_to(np.eye(3), (count, 3, 3)))
        if parent >= 0:
            turn = turns[parent] @ turn
            place = places[parent] + np.einsum("fij,fj->fi", turns[parent], place)
        turns.append(turn)
        places.append(place)
    return np.stack(places, axis=1)


def read_bvh(path: Any, start: int = 0, stop: int | None = None) -> Motion:
    """A BVH motion capture file's joints and their world positions at every frame.

    Args:
        path: the `.bvh` file.
        start: the first frame to keep (default 0).
        stop: the frame after the last one kept (default: all), `frames[start:stop]`.

    Returns:
        A `Motion`. Refused with a `BVHError` naming the file and the line: a truncated
        file, a frame count that does not match the frames, unknown channels.
    """
    path = Path(os.fspath(path))
    if not path.is_file():
        raise FileNotFoundError(f"BVH file {path} does not exist; give the path of a .bvh "
                                f"file (relative paths are from the current directory).")
    reader = _Reader(path)
    reader.expect("HIERARCHY")
    reader.expect("ROOT")
    joints: list = []
    _read_joint(reader, reader.next(), -1, joints)
    frames, frame_time = _read_frames(reader, sum(len(j[3]) for j in joints))
    kept = frames[start:stop]
    if len(kept) == 0:
        raise BVHError(f"{path}: frames [{start}:{stop}] of its {len(frames)} hold none; "
                       f"choose a range inside 0..{len(frames)}.")
    return Motion(names=tuple(j[0] for j in joints),
                  parents=np.array([j[1] for j in joints]),
                  offsets=np.array([j[2] for j in joints], float),
                  positions=_world_positions(joints, kept),
                  frame_time=float(frame_time), path=str(path))
