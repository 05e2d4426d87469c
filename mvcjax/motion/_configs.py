"""AnimatedDrawings' configuration files, read as they are: a character (`char_cfg.yaml`
with its `mask.png` and `texture.png`), a motion (`motion/*.yaml`), a retarget
(`retarget/*.yaml`) and a scene listing characters (`mvc/*.yaml`)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml


class ConfigError(ValueError):
    """A configuration file that cannot be used: the message names the file, the entry
    and the fix."""


class _Loader(yaml.SafeLoader):
    """YAML's safe loader, reading the `!!python/tuple` tags of AnimatedDrawings' files
    as lists (and nothing else of Python's)."""


_Loader.add_constructor("tag:yaml.org,2002:python/tuple",
                        lambda loader, node: loader.construct_sequence(node))

_PROJECTIONS = ("frontal", "sagittal", "pca")


def _read_yaml(path: Path, what: str) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} does not exist; give the path of "
                                f"AnimatedDrawings' {what} (a .yaml file).")
    try:
        data = yaml.load(path.read_text(), Loader=_Loader)
    except yaml.YAMLError as error:
        raise ConfigError(f"{path}: not readable YAML ({error}); fix the file.") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: a {what} is a YAML mapping of its entries, got "
                          f"{type(data).__name__}.")
    return data


def _entry(data: dict, key: str, path: Path, kind: Any, default: Any = ...) -> Any:
    """`data[key]`, checked to be a `kind`, or an error naming the file and the key."""
    if key not in data:
        if default is not ...:
            return default
        raise ConfigError(f"{path}: has no {key!r} entry; add it (see AnimatedDrawings' "
                          f"examples/config/README.md).")
    value = data[key]
    if not isinstance(value, kind):
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise ConfigError(f"{path}: {key!r} must be a {names}, got {value!r}.")
    return value


def resolve(name: Any, config: Path, what: str) -> Path:
    """A path named in a config file: as given (absolute, or from the current directory),
    else from the config's folder or any folder above it (AnimatedDrawings' files name
    paths from its repository's root)."""
    path = Path(os.fspath(name))
    if path.is_absolute() or path.exists():
        return path
    for folder in config.resolve().parents:
        if (folder / path).exists():
            return folder / path
    raise FileNotFoundError(f"{config}: its {what} {str(name)!r} was found neither from "
                            f"the current directory nor from the config's folders; fix "
                            f"the path.")


@dataclasses.dataclass(frozen=True)
class CharacterConfig:
    """A drawn character: its skeleton (joint names, pixel locations `(x, y)` with y down,
    parents) and its picture's files."""

    path: Path
    names: tuple[str, ...]
    parents: tuple[int, ...]
    pixels: np.ndarray
    size: tuple[int, int]
    mask: Path
    texture: Path

    @classmethod
    def read(cls, path: Any) -> CharacterConfig:
        path = Path(os.fspath(path))
        if path.is_dir():
            path = path / "char_cfg.yaml"
        data = _read_yaml(path, "character config")
        rows, cols = (_entry(data, key, path, int) for key in ("height", "width"))
        joints = _entry(data, "skeleton", path, list)
        try:
            names = tuple(str(joint["name"]) for joint in joints)
            pixels = np.array([joint["loc"] for joint in joints], float).reshape(-1, 2)
            parent_names = [joint["parent"] for joint in joints]
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"{path}: each skeleton joint needs name, loc [x, y] and "
                              f"parent (null for the root); {error!r}.") from None
        unknown = [p for p in parent_names if p is not None and p not in names]
        roots = [n for n, p in zip(names, parent_names) if p is None]
        if unknown or len(roots) != 1 or len(set(names)) != len(names):
            raise ConfigError(f"{path}: the skeleton must have distinct joint names, one "
                              f"root (parent null) and parents among its joints; unknown "
                              f"parents {unknown}, roots {roots}.")
        cls._check_inside(path, names, pixels, rows, cols)
        return cls(path=path, names=names, pixels=pixels, size=(rows, cols),
                   parents=tuple(-1 if p is None else names.index(p) for p in parent_names),
                   mask=path.parent / "mask.png", texture=path.parent / "texture.png")

    @staticmethod
    def _check_inside(path, names, pixels, rows, cols) -> None:
        outside = [n for n, (x, y) in zip(names, pixels)
                   if not (0 <= x < cols and 0 <= y < rows)]
        if outside:
            raise ConfigError(f"{path}: joints {outside} lie outside the {cols}x{rows} "
                              f"picture; their loc is [x, y] in pixels from the top left.")


@dataclasses.dataclass(frozen=True)
class MotionConfig:
    """Which BVH clip, which of its frames, and how it stands (up axis, forward, scale)."""

    path: Path
    bvh: Path
    start: int
    stop: int | None
    ground: str
    forward: tuple[tuple[str, str], ...]
    scale: float
    up: str
    frame_time: float | None

    @classmethod
    def read(cls, path: Any) -> MotionConfig:
        path = Path(os.fspath(path))
        data = _read_yaml(path, "motion config")
        up = _entry(data, "up", path, str)
        if up not in ("+y", "+z"):
            raise ConfigError(f"{path}: up is '+y' or '+z' (the clip's up axis), got {up!r}.")
        forward = _entry(data, "forward_perp_joint_vectors", path, list)
        if not forward or any(not isinstance(p, list) or len(p) != 2 for p in forward):
            raise ConfigError(f"{path}: forward_perp_joint_vectors is a list of joint "
                              f"pairs [[LeftShoulder, RightShoulder], ...], got {forward!r}.")
        scale = _entry(data, "scale", path, (int, float))
        if not scale > 0:
            raise ConfigError(f"{path}: scale must be above 0, got {scale!r}.")
        stop = _entry(data, "end_frame_idx", path, (int, type(None)), None)
        return cls(path=path, bvh=resolve(_entry(data, "filepath", path, str), path,
                                          "BVH filepath"),
                   start=_entry(data, "start_frame_idx", path, int, 0), stop=stop,
                   ground=_entry(data, "groundplane_joint", path, str),
                   forward=tuple((str(a), str(b)) for a, b in forward),
                   scale=float(scale), up=up,
                   frame_time=_entry(data, "frame_time", path, (int, float, type(None)), None))


@dataclasses.dataclass(frozen=True)
class RetargetConfig:
    """How a clip's limbs are projected onto the picture and mapped onto the character's
    joints: AnimatedDrawings' retarget file."""

    path: Path
    start: np.ndarray
    projections: tuple[tuple[str, str, tuple[str, ...]], ...]
    parts: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...]
    offset_group: str
    offset_bvh: tuple[tuple[str, ...], ...]
    offset_char: tuple[tuple[str, ...], ...]
    mapping: tuple[tuple[str, str, str], ...]
    checks: tuple[tuple[str, str, str, str], ...]

    @classmethod
    def read(cls, path: Any) -> RetargetConfig:
        path = Path(os.fspath(path))
        data = _read_yaml(path, "retarget config")
        try:
            start = np.array(_entry(data, "char_starting_location", path, list), float)
            projections = tuple((str(g["name"]), str(g["method"]),
                                 tuple(map(str, g["bvh_joint_names"])))
                                for g in _entry(data, "bvh_projection_bodypart_groups", path, list))
            parts = tuple((tuple(map(str, g["char_joints"])),
                           tuple(map(str, g["bvh_depth_drivers"])))
                          for g in _entry(data, "char_bodypart_groups", path, list))
            offset = _entry(data, "char_bvh_root_offset", path, dict)
            mapping = tuple((str(char), str(a), str(b)) for char, (a, b) in
                            _entry(data, "char_joint_bvh_joints_mapping", path, dict).items())
            checks = tuple(tuple(map(str, c)) for c in data.get("char_runtime_checks") or ())
            result = cls(path=path, start=start, projections=projections, parts=parts,
                         offset_group=str(offset["bvh_projection_bodypart_group_for_offset"]),
                         offset_bvh=tuple(tuple(map(str, c)) for c in offset["bvh_joints"]),
                         offset_char=tuple(tuple(map(str, c)) for c in offset["char_joints"]),
                         mapping=mapping, checks=checks)
        except (KeyError, TypeError, ValueError) as error:
            raise ConfigError(f"{path}: an entry is missing or malformed ({error!r}); "
                              f"compare with AnimatedDrawings' "
                              f"examples/config/retarget/fair1_ppf.yaml.") from None
        for name, method, _ in projections:
            if method not in _PROJECTIONS:
                raise ConfigError(f"{path}: body part group {name!r} has projection method "
                                  f"{method!r}; use one of {', '.join(_PROJECTIONS)}.")
        if start.shape != (3,):
            raise ConfigError(f"{path}: char_starting_location is [x, y, z], got "
                              f"{data['char_starting_location']!r}.")
        return result


@dataclasses.dataclass(frozen=True)
class SceneEntry:
    """One animated character of a scene: its three configs."""

    character: CharacterConfig
    motion: MotionConfig
    retarget: RetargetConfig


def read_scene(path: Any) -> tuple[SceneEntry, ...]:
    """The characters of an AnimatedDrawings scene file (`scene: ANIMATED_CHARACTERS:` a
    list of `character_cfg`, `motion_cfg`, `retarget_cfg`)."""
    path = Path(os.fspath(path))
    data = _read_yaml(path, "scene config")
    scene = _entry(data, "scene", path, dict)
    characters = _entry(scene, "ANIMATED_CHARACTERS", path, list)
    entries = []
    for item in characters:
        if not isinstance(item, dict) or not {"character_cfg", "motion_cfg",
                                              "retarget_cfg"} <= set(item):
            raise ConfigError(f"{path}: each of ANIMATED_CHARACTERS names character_cfg, "
                              f"motion_cfg and retarget_cfg, got {item!r}.")
        entries.append(SceneEntry(
            CharacterConfig.read(resolve(item["character_cfg"], path, "character_cfg")),
            MotionConfig.read(resolve(item["motion_cfg"], path, "motion_cfg")),
            RetargetConfig.read(resolve(item["retarget_cfg"], path, "retarget_cfg"))))
    if not entries:
        raise ConfigError(f"{path}: ANIMATED_CHARACTERS lists no character; add one.")
    return tuple(entries)
