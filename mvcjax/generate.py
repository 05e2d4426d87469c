"""Datasets of posed sprites: many sprites, each rigged and posed at random within
limits, written as pictures with their masks and handle targets.

The work is cut into units, one per sprite and `batch` poses, each written to its own
file once it is finished (written to a temporary name, then renamed), so that a run
interrupted at any point and started again loses nothing it finished and redoes only the
unit it was writing. A unit's random poses depend only on the seed, the sprite's name and
the unit's number: the dataset is the same whichever process writes which part and
however often it was resumed. Sprites are shared out between processes (`jax.distributed`)
by their order of name; a process's frames are split between its local devices.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time
import warnings
import zlib
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from ._animation import deform_frames
from .core import as_devices, is_real_number, progress_bar, whole_number
from .datasets import glyph, glyph_handles
from .geometry import Shape, cut_out, flipped_triangles, load_image
from .rendering import Checkerboard, Renderer, check_size, fill_texture, fit_window, to_pixels
from .rig import Rig

FORMAT = "mvcjax-posed-dataset"
VERSION = 1
SETTINGS_FILE = "dataset.json"
PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".bmp", ".gif", ".tif", ".tiff")
# Rounds of `batch` random poses drawn for one unit before its sprite is given up: poses
# are rejected when they fold a triangle or leave the picture.
MAX_ROUNDS = 16


@dataclasses.dataclass(frozen=True)
class PoseLimits:
    """How far the random poses of `write_dataset` go from rest.

    A pose moves the handles by random offsets, turns every bone about its start, and
    turns the whole pose about the shape's centre. Handles near each other move alike:
    the offsets are a smooth random field over the shape (a Gaussian process whose
    length scale is `spread`), so that two pins on one limb do not tear it apart. Poses
    that fold a triangle of the shape mesh (unless `folds`) or reach outside the picture
    are drawn again.

    Attributes:
        offset: the largest distance a handle moves, as a fraction of the shape's size
            (the longer side of its bounding box). Offsets are normal with half this as
            their standard deviation, cut at this.
        spread: the distance, as a fraction of the shape's size, over which handles
            move alike; 0 moves every handle on its own.
        turn: the largest turn of the whole pose, in degrees either way (uniform).
        bone_turn: the largest turn of a bone about its start, in degrees either way
            (uniform; its start moves with the offsets, its end follows).
        folds: keep poses that fold triangles too.
    """

    # Annotated Any: the checks below say what was wrong and how to fix it.
    offset: Any = 0.1
    spread: Any = 0.5
    turn: Any = 10.0
    bone_turn: Any = 30.0
    folds: Any = False

    def __post_init__(self):
        for name in ("offset", "spread", "turn", "bone_turn"):
            value = getattr(self, name)
            if not is_real_number(value) or not np.isfinite(value) or value < 0:
                raise ValueError(f"PoseLimits({name}={value!r}): give a finite number >= 0.")
        if not isinstance(self.folds, (bool, np.bool_)):
            raise TypeError(f"PoseLimits(folds={self.folds!r}): folds is True or False.")

    def draw(self, rng: np.random.Generator, rest: np.ndarray, bones: np.ndarray,
             centre: np.ndarray, size: float, count: int) -> np.ndarray:
        """`count` random targets `(count, t, 2)` about the rest targets `rest`, whose
        bones' rows are `bones` `(b, 2)`, for a shape of centre `centre` and size `size`."""
        t = len(rest)
        distance = np.linalg.norm(rest[:, None] - rest[None], axis=-1)
        if self.spread > 0:
            correlation = np.exp(-0.5 * (distance / (self.spread * size)) ** 2)
        else:
            correlation = (distance == 0).astype(np.float64)
        # Rows of coincident handles (a bone's pinned points, two handles at one spot)
        # make the correlation singular: a symmetric square root does not mind.
        values, vectors = np.linalg.eigh(correlation)
        root = (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T
        reach = self.offset * size
        offsets = np.einsum("ij,fjk->fik", root, rng.normal(size=(count, t, 2))) * (reach / 2)
        length = np.linalg.norm(offsets, axis=-1, keepdims=True)
        offsets *= np.minimum(1.0, reach / np.maximum(length, 1e-300))
        targets = rest[None] + offsets
        if len(bones):
            start, end = bones[:, 0], bones[:, 1]
            turns = np.radians(rng.uniform(-self.bone_turn, self.bone_turn, (count, len(bones))))
            arm = rest[end] - rest[start]
            targets[:, end] = targets[:, start] + _turned(arm[None], turns)
        turns = np.radians(rng.uniform(-self.turn, self.turn, count))
        return centre + _turned(targets - centre, turns[:, None])


def _turned(vectors: np.ndarray, radians: np.ndarray) -> np.ndarray:
    """`vectors` `(..., 2)` turned counterclockwise by `radians` (broadcast over `...`)."""
    c, s = np.cos(radians), np.sin(radians)
    x, y = vectors[..., 0], vectors[..., 1]
    return np.stack([c * x - s * y, s * x + c * y], axis=-1)


@dataclasses.dataclass
class DatasetReport:
    """What one process of `write_dataset` did.

    Attributes:
        written: pictures this call drew and wrote.
        resumed: pictures found already written by an earlier run, left as they were.
        skipped: sprites left out, by name, each with the reason (an unreadable file, a
            shape that could not be rigged, poses that kept folding).
        sprites: the sprites this process was given (by name), in order.
        seconds: wall time of the call.
        stages: where the time went, in seconds: `"rig"` (reading the sprites, meshing,
            rigging, building the renderers), `"pose"` (posing, compiling included),
            `"draw"` (drawing, compiling included) and `"write"` (compressing and
            writing the files).
        rejected: random poses drawn again because they folded or left the picture.
    """

    written: int = 0
    resumed: int = 0
    skipped: dict = dataclasses.field(default_factory=dict)
    sprites: list = dataclasses.field(default_factory=list)
    seconds: float = 0.0
    stages: dict = dataclasses.field(
        default_factory=lambda: dict.fromkeys(("rig", "pose", "draw", "write"), 0.0))
    rejected: int = 0

    @property
    def images_per_second(self) -> float:
        """Pictures written per second of wall time (everything included: reading,
        meshing, rigging, compiling, posing, drawing, writing)."""
        return self.written / self.seconds if self.seconds > 0 else 0.0


def glyph_sprites(letters: str, font: Any = None, size: int = 96) -> dict:
    """A font's glyphs as sprites for `write_dataset`: `{name: Shape}`, each named
    `U+XXXX` by its code point (names that differ in more than case, for any file
    system), `size` units tall per em, from `font` (a path; default DejaVu Sans).

    Each glyph is traced by `mvcjax.datasets.glyph` at four times `size` and scaled
    down, so that its outline's pixel steps are a quarter of a unit: smooth edges in
    pictures drawn about one pixel per unit.
    """
    if not isinstance(letters, str) or not letters.strip():
        raise ValueError(f"letters must be a string of visible characters, got {letters!r}.")
    size = whole_number(size, "size", what=" of pixels per em")
    sprites = {}
    for c in dict.fromkeys(letters):
        if not c.isspace():
            fine = glyph(c, font=font, size=4 * size)
            sprites[f"U+{ord(c):04X}"] = type(fine).from_polygon(
                fine.outer / 4, [h / 4 for h in fine.holes])
    return sprites


def write_dataset(
    sprites: Any,
    out: Any,
    *,
    poses: Any = 64,
    size: Any = (128, 128),
    limits: PoseLimits = PoseLimits(),
    handles: Callable | None = None,
    seed: Any = 0,
    batch: Any = 32,
    fill: Any = (0.1, 0.1, 0.1),
    rig_options: dict | None = None,
    progress: Any = None,
    devices: Any = None,
    process_index: Any = None,
    process_count: Any = None,
) -> DatasetReport:
    """Rig every sprite, pose it at random within `limits`, and write the posed pictures,
    their masks and their handle targets under `out`.

    Each sprite is rigged as a user would (`Shape.from_image` of its alpha, a picture
    without alpha keyed by `cut_out` from its corner colour, `Rig.build`), posed by
    `deform_frames` and drawn by `Renderer.frames` in a window that holds the rest shape
    with room for the largest offset and turn. Output: `out/dataset.json` (the settings),
    `out/<sprite>/<unit>.npz` per `batch` poses, and `out/report-<process>.json`;
    `read_dataset(out)` reads it back. Run it again with the same settings to finish
    an interrupted dataset: finished units are kept, and new sprites are added.

    Args:
        sprites: a folder of pictures (PNG with alpha; JPEG and other opaque pictures are
            keyed from their corner colour; other files are skipped, by name), a list of
            picture paths, or a mapping `{name: picture or Shape}` (a picture as
            `load_image` takes it; a `Shape` is drawn filled with `fill`; see
            `glyph_sprites`).
        out: the folder to write (made if missing). One that holds a dataset written with
            other settings is refused.
        poses: random poses per sprite.
        size: `(rows, cols)` of the pictures, or one number for squares.
        limits: how far poses go (`PoseLimits`).
        handles: a function of the `Shape` giving its handles, as `Rig.build` takes them
            (points and `mvcjax.Bone`s; bones are turned about their start). Default:
            `mvcjax.datasets.glyph_handles`, pins across the shape at three heights.
        seed: the random seed (an integer); a unit's poses depend on it, the sprite's
            name and the unit's number only.
        batch: poses per unit (per file, and per compiled batch).
        fill: how sprites given as a `Shape` are drawn: a colour `(r, g, b)` in [0, 1],
            or `mvcjax.advanced.Checkerboard()` (`Renderer.build`'s `fill`).
        rig_options: more keyword arguments of `Rig.build` (e.g. `shape_spacing`).
        progress: a progress bar (tqdm): True, False, or None for one on a terminal.
        devices: the devices this process poses and draws on (default: all of
            `jax.local_devices()`).
        process_index: this process's number (default `jax.process_index()`, which
            `jax.distributed` sets): sprite `i` of the sorted names goes to process
            `i % process_count`.
        process_count: how many processes share the sprites (default
            `jax.process_count()`).

    Returns:
        A `DatasetReport` of this process's work.
    """
    started = time.perf_counter()
    job = _checked_job(poses, size, limits, handles, seed, batch, fill, rig_options, devices,
                       process_index, process_count)
    sources, skipped = _sources(sprites)
    out = _open_folder(out, job.settings())
    mine = list(sources)[job.process_index::job.process_count]
    report = DatasetReport(sprites=mine)
    report.skipped.update(skipped)
    with progress_bar(len(mine) * job.poses, progress, "posed pictures") as bar:
        for name in mine:
            _write_sprite(out, name, sources[name], job, report, bar)
    report.seconds = time.perf_counter() - started
    _write_json(out / f"report-{job.process_index}.json", dataclasses.asdict(report)
                | {"images_per_second": report.images_per_second})
    if mine and len(report.skipped) >= len(mine) and not report.written + report.resumed:
        reasons = "; ".join(f"{k}: {v}" for k, v in list(report.skipped.items())[:5])
        raise ValueError(f"No sprite could be posed ({reasons}).")
    return report


@dataclasses.dataclass(frozen=True)
class _Job:
    """The checked settings of one `write_dataset` call."""

    poses: int
    batch: int
    rows: int
    cols: int
    limits: PoseLimits
    seed: int
    fill: Checkerboard | list[float]
    handles: Callable | None
    rig_options: dict
    process_index: int
    process_count: int
    devices: Any

    def settings(self) -> dict:
        """What `dataset.json` records: a dataset is resumed only with the same."""
        return {
            "format": FORMAT, "version": VERSION, "size": [self.rows, self.cols],
            "poses": self.poses, "batch": self.batch, "seed": self.seed,
            "limits": dataclasses.asdict(self.limits),
            "fill": self.fill if isinstance(self.fill, list) else repr(self.fill),
            "handles": _name_of(self.handles), "rig_options": repr(self.rig_options),
        }

    def unit_size(self, unit: int) -> int:
        """Poses in unit `unit` (the last may hold fewer than `batch`)."""
        return _unit_size(unit, self.poses, self.batch)


def _checked_job(poses, size, limits, handles, seed, batch, fill, rig_options, devices,
                 process_index, process_count) -> _Job:
    """`write_dataset`'s arguments checked, each refused naming it, and their defaults
    filled in."""
    poses = whole_number(poses, "poses", what=" of poses per sprite")
    batch = whole_number(batch, "batch", what=" of poses per unit")
    rows, cols = check_size((size, size) if isinstance(size, (int, np.integer)) else size)
    if not isinstance(limits, PoseLimits):
        raise TypeError(f"limits must be an mvcjax.generate.PoseLimits, got "
                        f"{type(limits).__name__}.")
    seed = whole_number(seed, "seed", minimum=0)
    fill_texture(fill, np.zeros((1, 2)))  # refused here, naming it, rather than per sprite
    fill = fill if isinstance(fill, Checkerboard) else [float(c) for c in fill]  # as JSON has it
    if handles is not None and not callable(handles):
        raise TypeError(f"handles must be a function of the Shape giving its handles, got "
                        f"{type(handles).__name__}.")
    rig_options = dict(rig_options or {})
    process_index = jax.process_index() if process_index is None else process_index
    process_count = jax.process_count() if process_count is None else process_count
    process_count = whole_number(process_count, "process_count")
    process_index = whole_number(process_index, "process_index", minimum=0)
    if process_index >= process_count:
        raise ValueError(f"process_index ({process_index}) must be below process_count "
                         f"({process_count}).")
    devices = as_devices(jax.local_devices() if devices is None else devices)
    return _Job(poses, batch, rows, cols, limits, seed, fill, handles, rig_options,
                process_index, process_count, devices)


def _write_sprite(out: pathlib.Path, name: str, source, job: _Job, report: DatasetReport,
                  bar) -> None:
    """Rig sprite `name`, then pose, draw and write its units not yet written, counting
    them in `report` and on `bar`; a sprite that cannot be rigged or posed is skipped."""
    units = -(-job.poses // job.batch)
    todo = [u for u in range(units) if not _unit_path(out, name, u).exists()]
    report.resumed += sum(job.unit_size(u) for u in range(units) if u not in todo)
    bar.update(job.poses - sum(job.unit_size(u) for u in todo))
    if not todo:
        return
    clock = time.perf_counter()
    try:
        sprite = _Sprite.build(name, source, job.handles, job.rig_options, job.limits,
                               (job.rows, job.cols), job.fill)
    except (OSError, ValueError, TypeError) as error:
        _skip(report, name, f"{type(error).__name__}: {error}")
        bar.update(sum(job.unit_size(u) for u in todo))
        return
    clock = _lap(report, "rig", clock)
    for unit in todo:
        rng = np.random.default_rng([job.seed, zlib.crc32(name.encode()), unit])
        drawn = sprite.pose(rng, job.batch, job.devices)
        if drawn is None:
            _skip(report, name, f"fewer than {job.batch} of {MAX_ROUNDS * job.batch} random "
                  "poses were free of folds and inside the picture; lower "
                  "PoseLimits(offset=, turn=, bone_turn=), or allow folds=True")
            break
        targets, vertices, rejected = drawn
        keep = job.unit_size(unit)
        clock = _lap(report, "pose", clock)
        pictures = sprite.renderer.frames(vertices[:keep], chunk=min(job.batch, 16),
                                          progress=False, devices=job.devices)
        clock = _lap(report, "draw", clock)
        _write_unit(_unit_path(out, name, unit), sprite, targets[:keep], pictures,
                    unit, job.process_index)
        clock = _lap(report, "write", clock)
        report.written += keep
        report.rejected += rejected
        bar.update(keep)


def read_dataset(out: Any) -> dict:
    """A dataset written by `write_dataset`, by sprite: `{name: {"images": (N, rows,
    cols, 4) uint8 RGBA, "masks": (N, rows, cols) bool, "targets": (N, t, 2) handle
    targets in the shape's coordinates, "keypoints": (N, t, 2) the same as (col, row)
    positions in the pictures, "rest": (t, 2), "window": (4,)}}`, units in order."""
    out = pathlib.Path(out)
    if not (out / SETTINGS_FILE).is_file():
        raise FileNotFoundError(f"{out} holds no posed dataset (no {SETTINGS_FILE}); write "
                                "one with mvcjax.generate.write_dataset.")
    data = {}
    for folder in sorted(p for p in out.iterdir() if p.is_dir()):
        files = sorted(folder.glob("[0-9]*.npz"))
        if not files:
            continue
        parts = [dict(np.load(f)) for f in files]
        data[folder.name] = {key: np.concatenate([p[key] for p in parts])
                             for key in ("images", "masks", "targets", "keypoints")}
        data[folder.name].update(rest=parts[0]["rest"], window=parts[0]["window"])
    return data


@dataclasses.dataclass
class _Sprite:
    """One sprite rigged and ready to pose: its rig, renderer, rest targets and bones."""

    rig: Any
    renderer: Any
    rest: np.ndarray
    bones: np.ndarray
    centre: np.ndarray
    size: float
    limits: PoseLimits

    @classmethod
    def build(cls, name, source, handles, rig_options, limits, shape, fill) -> _Sprite:
        picture = None
        if isinstance(source, Shape):
            outline = source
        else:
            picture = load_image(source)
            if picture[..., 3].min() >= 1.0:  # opaque: key out the corner's colour
                picture = cut_out(picture)
            outline = Shape.from_image(picture[..., 3] > 0.5, component=0)
        pins = (handles or (lambda s: np.concatenate(glyph_handles(s))))(outline)
        rig = Rig.build(outline, pins, **rig_options)
        rest = np.asarray(rig.handle_positions, np.float64)
        vertices = np.asarray(rig.shape_mesh.vertices, np.float64)
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        centre, extent = 0.5 * (lo + hi), float((hi - lo).max())
        # Room for the largest move: the rest shape turned as far as the limits allow
        # about its centre, and a handle's offset on top.
        reach = (np.linalg.norm(vertices - centre, axis=1).max() if limits.turn > 0
                 else 0.5 * extent)
        reach += limits.offset * extent
        window = fit_window(np.array([centre - reach, centre + reach]), shape, margin=0.02)
        renderer = Renderer.build(rig, picture, size=shape, window=window, fill=fill)
        return cls(rig, renderer, rest, np.asarray(rig.handles.bones, np.int64).reshape(-1, 2),
                   centre, extent, limits)

    def pose(self, rng, count: int, devices) -> tuple | None:
        """`count` random poses free of folds (unless allowed) and inside the window:
        their targets, deformed vertices and the number rejected; None if too few."""
        mesh = self.rig.shape_mesh
        kept_targets, kept_vertices, rejected = [], [], 0
        for _ in range(MAX_ROUNDS):
            targets = self.limits.draw(rng, self.rest, self.bones, self.centre, self.size,
                                       count)
            vertices = np.asarray(deform_frames(self.rig, targets, devices=devices))
            ok = np.isfinite(vertices).all(axis=(1, 2)) & ~self.renderer.leaves_window(vertices)
            if not self.limits.folds:
                ok &= flipped_triangles(mesh.vertices, vertices, mesh.faces) == 0
            rejected += int((~ok).sum())
            kept_targets.append(targets[ok])
            kept_vertices.append(vertices[ok])
            if sum(len(k) for k in kept_targets) >= count:
                return (np.concatenate(kept_targets)[:count],
                        np.concatenate(kept_vertices)[:count], rejected)
        return None


def _sources(sprites) -> tuple[dict, dict]:
    """The sprites by name (sorted), and the files skipped with why."""
    skipped = {}
    if isinstance(sprites, (str, os.PathLike)):
        folder = pathlib.Path(sprites)
        if not folder.is_dir():
            raise FileNotFoundError(f"sprites: {folder} is not a folder; give a folder of "
                                    "pictures, a list of paths or a {name: picture} mapping.")
        files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
        for p in files:
            if p.suffix.lower() not in PICTURE_SUFFIXES:
                skipped[p.name] = f"not a picture ({p.suffix or 'no suffix'})"
                _warn(p.name, skipped[p.name])
        sprites = [p for p in files if p.suffix.lower() in PICTURE_SUFFIXES]
    if isinstance(sprites, dict):
        sources = {}
        for name, source in sprites.items():
            if not isinstance(name, str) or not name or name != pathlib.Path(name).name \
                    or name.startswith("."):
                raise ValueError(f"sprite name {name!r} must be a plain file name (no folders, "
                                 "not starting with a dot): it names the sprite's folder.")
            sources[name] = source
    elif isinstance(sprites, (list, tuple)):
        sources = {}
        for p in map(pathlib.Path, sprites):
            if p.name in sources:
                raise ValueError(f"two sprites are named {p.name}; give them distinct file "
                                 "names, or pass a {name: path} mapping.")
            sources[p.name] = p
    else:
        raise TypeError(f"sprites must be a folder, a list of picture paths or a "
                        f"{{name: picture or Shape}} mapping, got {type(sprites).__name__}.")
    if not sources:
        raise ValueError(f"sprites holds no picture (skipped: {skipped or 'nothing'}).")
    for name, source in sources.items():
        if not isinstance(source, Shape) and isinstance(source, (str, os.PathLike)):
            try:
                from PIL import Image

                with Image.open(source) as image:
                    image.verify()
            except Exception as error:  # any reason Pillow gives: the file is left out
                skipped[name] = f"unreadable picture ({type(error).__name__}: {error})"
                _warn(name, skipped[name])
    return {k: sources[k] for k in sorted(sources) if k not in skipped}, skipped


def _lap(report: DatasetReport, stage: str, since: float) -> float:
    now = time.perf_counter()
    report.stages[stage] += now - since
    return now


def _warn(name: str, reason: str, stacklevel: int = 4) -> None:
    """Warn that sprite `name` is left out, pointing at the call of `write_dataset`:
    `stacklevel` counts the frames from here to its caller (4 from `_sources`)."""
    warnings.warn(f"write_dataset skips sprite {name}: {reason}.", stacklevel=stacklevel)


def _skip(report: DatasetReport, name: str, reason: str) -> None:
    """Record sprite `name` as skipped, and warn the caller of `write_dataset` (which
    calls `_write_sprite`, which calls this)."""
    report.skipped[name] = reason
    _warn(name, reason, stacklevel=5)


def _open_folder(out, settings: dict) -> pathlib.Path:
    """The output folder, made if missing, with its settings file; refused if it holds a
    dataset with other settings. Every process writes the same settings, atomically."""
    out = pathlib.Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"out: {out} is a file; give a folder for the dataset.")
    out.mkdir(parents=True, exist_ok=True)
    path = out / SETTINGS_FILE
    if path.exists():
        try:
            there = json.loads(path.read_text())
        except (OSError, ValueError) as error:
            raise ValueError(f"out: {path} cannot be read ({error}); give a new folder, or "
                             "remove that file.") from None
        if there != settings:
            changed = ", ".join(f"{k}: {there.get(k)!r} there, {settings.get(k)!r} now"
                                for k in sorted(set(there) | set(settings))
                                if there.get(k) != settings.get(k))
            raise ValueError(f"out: {out} holds a dataset written with other settings "
                             f"({changed}). Resume it with the same settings, or write to "
                             "another folder.")
    else:
        _write_json(path, settings)
    return out


def _write_json(path: pathlib.Path, value: dict) -> None:
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(json.dumps(value, indent=1, default=str) + "\n")
    os.replace(temporary, path)


def _unit_path(out: pathlib.Path, name: str, unit: int) -> pathlib.Path:
    return out / name / f"{unit:05d}.npz"


def _unit_size(unit: int, poses: int, batch: int) -> int:
    return min(batch, poses - unit * batch)


def _write_unit(path: pathlib.Path, sprite: _Sprite, targets, pictures, unit: int,
                process: int) -> None:
    """One unit's arrays, written under a temporary name and renamed when complete."""
    rows, cols = sprite.renderer.shape
    window = np.asarray(sprite.renderer.window, np.float64)
    path.parent.mkdir(exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    np.savez_compressed(
        temporary,
        images=pictures,
        masks=pictures[..., 3] >= 128,
        targets=targets.astype(np.float32),
        keypoints=np.asarray(to_pixels(targets, window, rows, cols), np.float32),
        rest=sprite.rest.astype(np.float32),
        window=window,
        unit=np.int64(unit),
        process=np.int64(process),
    )
    os.replace(temporary, path)


def _name_of(function) -> str | None:
    if function is None:
        return None
    return f"{getattr(function, '__module__', '?')}.{getattr(function, '__qualname__', '?')}"
