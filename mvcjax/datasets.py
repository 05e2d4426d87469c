"""Built-in shapes: the horse, and the paper's character, flower and stick, each with
default handles and a drag; `model(name)` bundles them with their `Rig.build` options."""

from __future__ import annotations

import dataclasses

import numpy as np
import shapely
from shapely import affinity

from .character import Layer
from .geometry import Shape, load_image
from .rig import Bone, PaperControl, Rig, parse_handles


def horse(tolerance: float = 1.0) -> Shape:
    """The silhouette of `skimage.data.horse()` (400 x 328 pixels, y up), as a `Shape`.

    The outline is simplified to within `tolerance` pixels; noise holes under 10 square
    pixels are filled. The two front legs are separated by a slot about one pixel wide
    over much of their length: a test for any control mesh.
    """
    from skimage import data

    return Shape.from_image(~data.horse(), tolerance=tolerance, min_hole_area=10.0)


def horse_handles() -> np.ndarray:
    """Default handles on the horse, `(5, 2)`: the right front hoof, the two hind
    hooves, the middle of the back and the head. The left front hoof is left free.
    """
    return np.array([[280.0, 20.0], [62.0, 20.0], [125.0, 27.0], [200.0, 230.0], [372.0, 238.0]])


def horse_drag() -> np.ndarray:
    """The demo's drag: offsets `(5, 2)` for `horse_handles()`, the front hoof lifted
    forward, the head raised, the other handles kept."""
    return np.array([[45.0, 40.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [10.0, 25.0]])


# ---- the paper's three models -------------------------------------------------------
#
# Built from unions of capsules, discs and ellipses (shapely), in abstract units about
# 200 tall or long, y up. Each comes with default handles, a drag like the paper's
# figures 3-5, and the `Rig.build` options that size its meshes like the paper's Table 1.


def _capsule(a, b, radius: float) -> shapely.Polygon:
    return shapely.LineString([a, b]).buffer(radius, quad_segs=8)


def _ellipse(centre, rx: float, ry: float, angle: float = 0.0) -> shapely.Polygon:
    disc = shapely.Point(centre).buffer(1.0, quad_segs=8)
    return affinity.rotate(affinity.scale(disc, rx, ry), angle, origin=tuple(centre))


def _from_union(parts) -> Shape:
    # The simplification drops the union's dense arc vertices (0.3 units off the curve
    # at most): the shape mesh resamples the outline at its own spacing anyway, and a
    # dense outline would put a floor under its vertex count.
    outline = shapely.unary_union(parts).simplify(0.3)
    return Shape.from_polygon(np.asarray(outline.exterior.coords))


def _rotate(point, centre, degrees: float) -> np.ndarray:
    """`point` turned `degrees` counter-clockwise about `centre`."""
    t = np.radians(degrees)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    centre = np.asarray(centre, np.float64)
    return centre + rot @ (np.asarray(point, np.float64) - centre)


# The character: a front-facing figure, arms held out 20 degrees below horizontal, legs
# apart. Left and right are the viewer's (x < 0 is the left).
_HEAD = (0.0, 175.0)
_SHOULDERS = ((-18.0, 141.0), (18.0, 141.0))
_HIPS = ((-13.0, 91.0), (13.0, 91.0))
_ARM, _LEG = 60.0, (20.0, -80.0)  # arm length; hip-to-foot vector (mirrored on the left)
_ARM_DOWN = 20.0  # degrees below horizontal
_WRIST_IN = 12.0  # handles sit this far in from the ends of the limbs


def _hands() -> np.ndarray:
    t = np.radians(_ARM_DOWN)
    return np.array([[s[0] + np.sign(s[0]) * _ARM * np.cos(t), s[1] - _ARM * np.sin(t)]
                     for s in _SHOULDERS])


def _feet() -> np.ndarray:
    return np.array([[h[0] + np.sign(h[0]) * _LEG[0], h[1] + _LEG[1]] for h in _HIPS])


def character() -> Shape:
    """A human figure, 171 x 195 units (x from -85 to 85, feet at y = 0, y up), as a
    `Shape`.

    A round head (radius 20) on an elliptical torso (56 x 84), two arms (22 wide, held
    out 20 degrees below horizontal) and two legs (22 wide, apart): one simple polygon,
    no holes.
    """
    parts = [shapely.Point(_HEAD).buffer(20.0, quad_segs=8), _ellipse((0.0, 116.0), 28.0, 42.0)]
    parts += [_capsule(s, h, 11.0) for s, h in zip(_SHOULDERS, _hands())]
    parts += [_capsule(h, f, 11.0) for h, f in zip(_HIPS, _feet())]
    return _from_union(parts)


def character_handles() -> np.ndarray:
    """Default handles on the character, `(6, 2)` in the shape's units: the head, the
    pelvis, the left and right wrists, the left and right ankles.

    Wrists and ankles sit 12 units in from the ends of the limbs rather than at their
    tips: the control mesh then has an inner vertex beyond each, and the tip's control
    triangles are not a fan around a single handle, which folds when the limb turns.
    """
    def inward(end, root):
        d = np.asarray(root) - end
        return end + _WRIST_IN * d / np.linalg.norm(d)

    wrists = [inward(h, s) for h, s in zip(_hands(), _SHOULDERS)]
    ankles = [inward(f, h) for f, h in zip(_feet(), _HIPS)]
    return np.array([_HEAD, (0.0, 103.0), *wrists, *ankles])


def character_drag() -> np.ndarray:
    """Offsets `(6, 2)` for `character_handles()`: the right arm raised to wave (the
    wrist turned 75 degrees up about the shoulder: 58 units), the left leg kicked out
    sideways (the ankle turned 45 degrees about the hip: 54 units); the head,
    pelvis, left wrist and right ankle are anchors (zero offset)."""
    h = character_handles()
    drag = np.zeros_like(h)
    drag[3] = _rotate(h[3], _SHOULDERS[1], 75.0) - h[3]
    drag[4] = _rotate(h[4], _HIPS[0], -45.0) - h[4]
    return drag


# The flower: six petals around a disc on a straight stem, one leaf.
_FLOWER_CENTRE = (0.0, 152.0)


def flower() -> Shape:
    """A flower, 90 x 202 units (x from -45 to 45, the stem's foot at y = 0, y up), as
    a `Shape`.

    Six round-tipped petals (40 long, 29 wide) around a disc (radius 18) centred at
    (0, 152), on a straight stem 14 wide, with one leaf (40 x 14) on the right.
    """
    cx, cy = _FLOWER_CENTRE
    parts = [shapely.Point(cx, cy).buffer(18.0, quad_segs=8)]
    for k in range(6):
        a = np.pi / 2 + k * np.pi / 3
        parts.append(_ellipse((cx + 30.0 * np.cos(a), cy + 30.0 * np.sin(a)), 20.0, 14.67,
                              np.degrees(a)))
    parts.append(_capsule((0.0, 7.0), (0.0, cy - 18.0), 7.0))
    leaf = np.radians(35.0)
    parts.append(_ellipse((17.0 * np.cos(leaf), 37.0 + 17.0 * np.sin(leaf)), 20.0, 7.0, 35.0))
    return _from_union(parts)


def flower_handles() -> np.ndarray:
    """Default handles on the flower, `(3, 2)` in the shape's units: two on the stem
    near its foot, at y = 10 and y = 29 (together they clamp the stem's direction, which
    one handle alone would leave free to turn), and the centre of the flower's head."""
    return np.array([[0.0, 10.0], [0.0, 29.0], _FLOWER_CENTRE])


def flower_drag() -> np.ndarray:
    """Offsets `(3, 2)` for `flower_handles()`: the head pulled 75 units right and 40
    down (85 units), bending the stem over sideways; the two stem handles are anchors."""
    return np.array([[0.0, 0.0], [0.0, 0.0], [75.0, -40.0]])


# The stick: a bar along the x axis.
_STICK_LENGTH = 200.0
_STICK_BEND = 90.0  # degrees the drag turns the right end


def stick() -> Shape:
    """A straight bar, 227 x 30 units (x from -113.5 to 113.5, centred on the x axis),
    as a `Shape`.

    The end caps are half discs centred at x = +-100. The half width eases from 15 in
    the middle to 13.5 at the ends (a 10% taper, barely visible): the sides are then
    not straight lines, whose outward offset would be two long edges that the control
    polygon keeps whole, however small the control spacing is.
    """
    half = _STICK_LENGTH / 2
    x = np.linspace(-half, half, 31)
    w = 15.0 * (1.0 - 0.1 * (x / half) ** 2)
    a = np.linspace(np.pi / 2, -np.pi / 2, 9)[1:-1]
    right = np.stack([half + w[-1] * np.cos(a), w[-1] * np.sin(a)], axis=1)
    left = np.stack([-half - w[0] * np.cos(a), -w[0] * np.sin(a)], axis=1)
    top = np.stack([x, w], axis=1)
    bottom = np.stack([x, -w], axis=1)[::-1]
    return Shape.from_polygon(np.concatenate([top, right, bottom, left]))


def stick_handles() -> np.ndarray:
    """Default handles on the stick, `(4, 2)` in the shape's units, on its axis: the
    left end (x = -100), x = -70 (the two clamp the left end's direction), the middle
    and the right end (x = 100)."""
    return np.array([[-100.0, 0.0], [-70.0, 0.0], [0.0, 0.0], [100.0, 0.0]])


def stick_drag() -> np.ndarray:
    """Offsets `(4, 2)` for `stick_handles()` that bend the stick's axis into a quarter
    circle (radius 127 units) curling up from the clamped left end: every handle goes to
    the point of that arc at the same distance along the axis; the right end moves by
    (-73, 127), the middle by (-10, 37), the clamp's second handle by 3.5."""
    h = stick_handles()
    radius = _STICK_LENGTH / np.radians(_STICK_BEND)
    t = (h[:, 0] + _STICK_LENGTH / 2) / radius
    arc = np.stack([-_STICK_LENGTH / 2 + radius * np.sin(t), radius * (1.0 - np.cos(t))], axis=1)
    return arc - h


# ---- models: a shape, its handles, a drag and its build options ----------------------


@dataclasses.dataclass(frozen=True, eq=False)
class Model:
    """A built-in shape ready to rig: its handles, a default drag and `Rig.build` options.

    Attributes:
        name: one of `MODEL_NAMES`.
        shape: the shape.
        handles: `(h, 2)` default handle points (read-only), on or inside the shape.
        drag: `(h, 2)` offsets of the default pose (read-only): the targets are
            `rig.handle_positions + drag`.
        options: keyword arguments for `Rig.build` (`shape_spacing`, and `control`, a
            `PaperControl(spacing, margin)`) that size the meshes like the paper's
            Table 1.
    """

    name: str
    shape: Shape
    handles: np.ndarray
    drag: np.ndarray
    options: dict = dataclasses.field(default_factory=dict)

    def rig(self, **overrides) -> Rig:
        """`Rig.build(shape, handles, **options)`, any option replaced by `overrides`
        (e.g. `dtype=jnp.float32`, `skinning=mvcjax.advanced.MVCSkinning()`)."""
        # Imported here: loading the datasets should not pull in JAX, nor make a cycle
        # through the package's __init__, which imports this module first.
        return Rig.build(self.shape, self.handles, **{**self.options, **overrides})


MODEL_NAMES = ("character", "flower", "stick", "horse")

# Spacings chosen so that the rigs come close to the paper's Table 1 (shape mesh
# vertices; control polygon + inner vertices): character 532; 32 + 34, flower 730;
# 44 + 76, stick 229; 24 + 19 (`tests/test_datasets.py` checks how close, and
# `docs/paper.md` gives the counts). The totals match within 15%; the split cannot: the
# control polygon's edges are at most the control spacing long, straight stretches
# included, while the inner vertices end up one to two spacings apart, so on limbs,
# stems and bars the polygon takes more of the vertices than the paper's did (even a
# disc only reaches the paper's ratio of about 1 : 1).
_OPTIONS = {
    "character": dict(shape_spacing=6.75, spacing=21.0, margin=12.0),
    "flower": dict(shape_spacing=4.6, spacing=11.0, margin=6.5),
    "stick": dict(shape_spacing=7.63, spacing=21.0, margin=14.0),
    "horse": {},
}


def model(name: str) -> Model:
    """The built-in model `name` (one of `MODEL_NAMES`) as a `Model`.

    "horse" has empty options: `Rig.build`'s defaults. Raises `ValueError` for any
    other name.
    """
    makers = {
        "character": (character, character_handles, character_drag),
        "flower": (flower, flower_handles, flower_drag),
        "stick": (stick, stick_handles, stick_drag),
        "horse": (horse, horse_handles, horse_drag),
    }
    if name not in makers:
        raise ValueError(f"Unknown model {name!r}; the models are {', '.join(MODEL_NAMES)}.")
    make_shape, make_handles, make_drag = makers[name]
    handles, drag = make_handles(), make_drag()
    handles.setflags(write=False)
    drag.setflags(write=False)
    sizes = dict(_OPTIONS[name])
    options = ({"shape_spacing": sizes.pop("shape_spacing"), "control": PaperControl(**sizes)}
               if sizes else {})
    return Model(name, make_shape(), handles, drag, options)


# ---- the fold suite's shapes ---------------------------------------------------------
#
# Shapes for the fold suite (`benchmarks/folds.py`): limbs turned far, a strip curled,
# letters bent. Each comes with handles that mix points and `Bone`s; the poses are
# functions of the rest targets in `benchmarks/folds.py`.


def character_bones(limbs: str = "arms") -> list:
    """Handles on `character()` with a `Bone` per arm or per leg, a list for `Rig.build`.

    `limbs="arms"`: the head and the pelvis as points, a bone along each arm from its
    shoulder to its wrist (left, then right), the two ankles as points: 8 target rows
    (head, pelvis, left shoulder, left wrist, right shoulder, right wrist, left ankle,
    right ankle). `limbs="legs"`: the head, the pelvis and the two wrists as points, a
    bone along each leg from its hip to its ankle (left, then right): 8 rows (head,
    pelvis, left wrist, right wrist, left hip, left ankle, right hip, right ankle). The
    points and bone ends are those of `character_handles()` and the character's
    shoulders and hips, which lie inside the torso.
    """
    h = character_handles()
    head, pelvis = tuple(h[0]), tuple(h[1])
    if limbs == "arms":
        return [head, pelvis, Bone(_SHOULDERS[0], h[2]), Bone(_SHOULDERS[1], h[3]),
                tuple(h[4]), tuple(h[5])]
    if limbs == "legs":
        return [head, pelvis, tuple(h[2]), tuple(h[3]), Bone(_HIPS[0], h[4]),
                Bone(_HIPS[1], h[5])]
    raise ValueError(f"limbs must be 'arms' or 'legs', got {limbs!r}.")


# The sprite: a front-facing figure drawn with Pillow, in its pixels with y up (the
# coordinates `Shape.from_image` gives). Arms hang 30 degrees out from the body, legs
# apart, feet pointing outwards. Left and right are the viewer's.
_SPRITE_SIZE = (240, 260)  # (width, height) in pixels
_SPRITE_TORSO = ((120.0, 130.0), 30.0, 45.0)  # centre, half width, half height
_SPRITE_HEAD = ((120.0, 206.0), 24.0)  # centre, radius
_SPRITE_NECK = ((111.0, 165.0), (129.0, 190.0))  # corners of a rectangle
_SPRITE_SHOULDERS = ((97.0, 158.0), (143.0, 158.0))
_SPRITE_HIPS = ((108.0, 95.0), (132.0, 95.0))
_SPRITE_ARM = (70.0, 30.0, 8.0)  # length, degrees out from hanging straight down, radius
_SPRITE_ANKLES = ((100.0, 24.0), (140.0, 24.0))
_SPRITE_LEG = 9.0  # radius
_SPRITE_FEET = (((90.0, 15.0), 16.0, 7.0), ((150.0, 15.0), 16.0, 7.0))  # centre, rx, ry
_SPRITE_IN = 10.0  # the wrist handles sit this far in from the hands' tips


def _sprite_hands(out: float = _SPRITE_ARM[1]) -> np.ndarray:
    """Where the arms end, hanging `out` degrees out from straight down."""
    length, _, _ = _SPRITE_ARM
    t = np.radians(out)
    return np.array([[s[0] + side * length * np.sin(t), s[1] - length * np.cos(t)]
                     for s, side in zip(_SPRITE_SHOULDERS, (-1.0, 1.0))])


_SKIN, _SHIRT, _SLEEVE = (236, 188, 150, 255), (52, 101, 164, 255), (32, 74, 135, 255)
_TROUSERS, _SHOES = (60, 60, 70, 255), (120, 70, 30, 255)


def _pixel(p) -> tuple[float, float]:
    """Shape coordinates (y up) to Pillow's (x, y down) on the sprite's canvas."""
    return (p[0], _SPRITE_SIZE[1] - 1 - p[1])


def _paint_ellipse(draw, centre, rx, ry, colour) -> None:
    x, y = _pixel(centre)
    draw.ellipse([x - rx, y - ry, x + rx, y + ry], fill=colour)


def _paint_capsule(draw, a, b, radius, colour) -> None:
    draw.line([_pixel(a), _pixel(b)], fill=colour, width=round(2 * radius))
    for p in (a, b):
        _paint_ellipse(draw, p, radius, radius, colour)


def _sprite_body(draw) -> None:
    """The sprite's legs, feet, neck, torso and head, drawn in that order."""
    for hip, ankle in zip(_SPRITE_HIPS, _SPRITE_ANKLES):
        _paint_capsule(draw, hip, ankle, _SPRITE_LEG, _TROUSERS)
    for centre, rx, ry in _SPRITE_FEET:
        _paint_ellipse(draw, centre, rx, ry, _SHOES)
    (x0, y0), (x1, y1) = _SPRITE_NECK
    draw.rectangle([*_pixel((x0, y1)), *_pixel((x1, y0))], fill=_SKIN)
    centre, rx, ry = _SPRITE_TORSO
    _paint_ellipse(draw, centre, rx, ry, _SHIRT)
    _paint_ellipse(draw, _SPRITE_HEAD[0], _SPRITE_HEAD[1], _SPRITE_HEAD[1], _SKIN)


def _drawn(*steps) -> np.ndarray:
    """A transparent canvas of the sprite's size with `steps(draw)` drawn on it, as
    `(rows, cols, 4)` uint8 RGBA."""
    from PIL import Image, ImageDraw

    image = Image.new("RGBA", _SPRITE_SIZE, (0, 0, 0, 0))
    draw = ImageDraw.Draw(image)
    for step in steps:
        step(draw)
    return np.asarray(image)


def sprite_picture() -> np.ndarray:
    """The sprite drawn with Pillow: a `(260, 240, 4)` RGBA picture (uint8, transparent
    background), a figure of five coloured parts (head, torso, arms, legs, feet) whose
    union is one silhouette.

    The head is a disc (radius 24) on a neck, the torso an ellipse (60 x 90 pixels), the
    arms capsules 16 wide and 70 long hanging 30 degrees out from the body, the legs
    capsules 18 wide, the feet ellipses pointing outwards. `sprite()` is its silhouette
    and `sprite_handles()` rigs it; `Renderer.build(rig, sprite_picture())` draws it
    posed.
    """
    def arms(draw):
        for s, h in zip(_SPRITE_SHOULDERS, _sprite_hands()):
            _paint_capsule(draw, s, h, _SPRITE_ARM[2], _SHIRT)
            _paint_ellipse(draw, h, _SPRITE_ARM[2] + 1.0, _SPRITE_ARM[2] + 1.0, _SKIN)

    return _drawn(arms, _sprite_body)


def sprite() -> Shape:
    """The silhouette of `sprite_picture()` (from its alpha, `Shape.from_image`), about
    125 x 220 pixels in a 240 x 260 picture, y up: one polygon, no holes."""
    return Shape.from_image(sprite_picture())


def sprite_handles() -> list:
    """Handles on `sprite()`, a list for `Rig.build`: a point on the chest, a `Bone`
    along each arm (shoulder to wrist: left, then right) and each leg (hip to ankle),
    and a point on each foot's toe. Target rows: chest, left shoulder, left wrist,
    right shoulder, right wrist, left hip, left ankle, right hip, right ankle, left
    toe, right toe (11)."""
    def inward(end, root, by):
        d = np.asarray(root) - end
        return end + by * d / np.linalg.norm(d)

    wrists = [inward(h, s, _SPRITE_IN - _SPRITE_ARM[2]) for h, s in
              zip(_sprite_hands(), _SPRITE_SHOULDERS)]
    toes = [(c[0] + side * 0.6 * rx, c[1]) for (c, rx, _), side in
            zip(_SPRITE_FEET, (-1.0, 1.0))]
    chest = (_SPRITE_TORSO[0][0], _SPRITE_TORSO[0][1] + 12.0)
    return [chest,
            *[Bone(s, w) for s, w in zip(_SPRITE_SHOULDERS, wrists)],
            *[Bone(h, a) for h, a in zip(_SPRITE_HIPS, _SPRITE_ANKLES)],
            *toes]


# The layered figure: the sprite's figure drawn as parts on layers of one canvas, with
# arms that hang over the torso's sides at rest (drawn over it) and a right hand of its
# own that holds no handle and follows the arm it overlaps.
_FIGURE_ARM_OUT = 12.0  # degrees out from hanging straight down
_FIGURE_HAND = 11.0  # the separate right hand's radius; its centre is past the arm's tip
_FIGURE_WRIST_IN = 14.0  # the wrist handles sit this far in from the arms' tips


def layered_figure() -> list:
    """A figure drawn in layers, bottom first, for `mvcjax.Character.build`: a list of
    four `mvcjax.advanced.Layer`s on one 240 x 260 canvas (straight RGBA floats).

    `"body"` (head, neck, torso, legs, feet, as `sprite_picture()`'s), `"left arm"`
    (with its hand) and `"right arm"`, capsules 16 wide and 70 long from the shoulders,
    hanging 12 degrees out so that they lie over the torso's sides, and `"right hand"`,
    a disc past the right arm's tip. `layered_figure_handles()` pins it; the right hand
    holds no handle and follows the right arm.
    """
    hands, radius = _sprite_hands(_FIGURE_ARM_OUT), _SPRITE_ARM[2]

    def left_arm(draw):
        _paint_capsule(draw, _SPRITE_SHOULDERS[0], hands[0], radius, _SLEEVE)
        _paint_ellipse(draw, hands[0], radius + 1.0, radius + 1.0, _SKIN)

    def right_arm(draw):
        _paint_capsule(draw, _SPRITE_SHOULDERS[1], hands[1], radius, _SLEEVE)

    def right_hand(draw):
        d = hands[1] - np.asarray(_SPRITE_SHOULDERS[1])
        _paint_ellipse(draw, hands[1] + 4.0 * d / np.linalg.norm(d), _FIGURE_HAND, _FIGURE_HAND,
                 _SKIN)

    return [Layer(name, load_image(_drawn(draw))) for name, draw in
            [("body", _sprite_body), ("left arm", left_arm), ("right arm", right_arm),
             ("right hand", right_hand)]]


def layered_figure_handles() -> list:
    """Handles on `layered_figure()`, a list for `Character.build`: a point on the chest,
    a `Bone` along each arm from its shoulder (inside the torso too, which it pins
    there) to its wrist (left, then right), and a point on each ankle. Target rows:
    chest, left shoulder, left wrist, right shoulder, right wrist, left ankle, right
    ankle (7)."""
    def inward(end, root):
        d = np.asarray(root) - end
        return end + _FIGURE_WRIST_IN * d / np.linalg.norm(d)

    chest = (_SPRITE_TORSO[0][0], _SPRITE_TORSO[0][1] + 12.0)
    return [chest, *[Bone(s, inward(h, s)) for s, h in zip(_SPRITE_SHOULDERS,
                                                          _sprite_hands(_FIGURE_ARM_OUT))],
            *[tuple(a) for a in _SPRITE_ANKLES]]


def layered_figure_wave(frames: int = 30, degrees: float = 110.0) -> np.ndarray:
    """`(frames, 7, 2)` targets for `layered_figure_handles()`: the right arm swings
    about its shoulder across the chest, `degrees` clockwise, and back down, everything
    else at rest."""
    rest, _, _ = parse_handles(layered_figure_handles())
    shoulder = rest[3]
    turn = np.radians(degrees) * np.sin(np.linspace(0.0, np.pi, frames))
    targets = np.repeat(rest[None], frames, axis=0)
    for k, angle in enumerate(turn):
        targets[k, 4] = _rotate(rest[4], shoulder, -np.degrees(angle))
    return targets


# The snake: a long strip along the x axis.
_SNAKE = (400.0, 20.0)  # length and width, round ends included


def snake(length: float = _SNAKE[0], width: float = _SNAKE[1], taper: float = 0.0) -> Shape:
    """A long strip with round ends, `length` x `width` (default 400 x 20 units), along
    the x axis from x = 0 to `length`, centred on y = 0: a capsule whose axis runs from
    `width / 2` to `length - width / 2`.

    With `taper > 0` the half width eases from `width / 2` in the middle to `(1 - taper)`
    times that at the ends (as `stick()`'s, whose 10% is barely visible): the sides are
    then curves, not the two long straight edges that the default control polygon keeps
    whole (one control edge a side, which cannot bend), however small the control spacing.
    """
    if not (np.isfinite(length) and np.isfinite(width) and 0 < width < length):
        raise ValueError(f"snake needs 0 < width < length, got length={length}, width={width}.")
    if not (np.isfinite(taper) and 0 <= taper < 1):
        raise ValueError(f"snake needs 0 <= taper < 1, got taper={taper}.")
    r = width / 2.0
    if taper == 0:
        return _from_union([_capsule((r, 0.0), (length - r, 0.0), r)])
    half = length / 2.0 - r * (1.0 - taper)  # the caps' centres, their radius the end's width
    x = np.linspace(-half, half, 41)
    w = r * (1.0 - taper * (x / half) ** 2)
    a = np.linspace(np.pi / 2, -np.pi / 2, 11)[1:-1]
    right = np.stack([half + w[-1] * np.cos(a), w[-1] * np.sin(a)], axis=1)
    left = np.stack([-half - w[0] * np.cos(a), -w[0] * np.sin(a)], axis=1)
    top = np.stack([x, w], axis=1)
    bottom = np.stack([x, -w], axis=1)[::-1]
    outline = np.concatenate([top, right, bottom, left]) + [length / 2.0, 0.0]
    return Shape.from_polygon(outline)


def snake_handles(length: float = _SNAKE[0], width: float = _SNAKE[1],
                  points: int = 6) -> list:
    """Handles on `snake(length, width)`, a list for `Rig.build`: two points on the axis
    at the tail (they clamp its direction), `points` points evenly along the axis
    between them and the head, and a `Bone` along the head end (its last tenth, from
    the back of the head to the snout). Target rows: the tail points, the points along
    the body, then the bone's start and end."""
    r = width / 2.0
    tail = [r + 0.5 * r, r + 0.5 * r + 0.075 * length]
    head = (length - r - 0.1 * length, length - r - 0.2 * r)
    body = np.linspace(tail[1], head[0], points + 2)[1:-1]
    return [*[(float(x), 0.0) for x in (*tail, *body)],
            Bone((head[0], 0.0), (head[1], 0.0))]


def snake_curl(rest: np.ndarray, degrees: float) -> np.ndarray:
    """Targets `(t, 2)` that curl a strip's axis (the x axis, every rest target on it,
    tail at the smallest x) into a circular arc turning `degrees` counter-clockwise
    from its first target to its last: each target goes to the point of the arc at the
    same distance along the axis, so the arc keeps the axis's length and the targets
    agree with each other (a bone's ends stay its length apart, to the arc's sag)."""
    rest = np.asarray(rest, np.float64)
    start, end = rest[:, 0].min(), rest[:, 0].max()
    if degrees == 0:
        return rest.copy()
    radius = (end - start) / np.radians(degrees)
    t = (rest[:, 0] - start) / radius
    arc = np.stack([start + radius * np.sin(t), rest[:, 1] + radius * (1.0 - np.cos(t))], axis=1)
    return arc


# Glyphs: letters of a font rendered to masks.


def glyph(letter: str, font=None, size: int = 200) -> Shape:
    """The letter `letter` rendered by Pillow from a TrueType font at `size` pixels (the
    font's em size), traced to a `Shape` (`Shape.from_image`, pixel units, y up).

    `font` is a path to a font file, or `None` for DejaVu Sans, which matplotlib ships
    (`matplotlib.font_manager.findfont("DejaVu Sans")`). A letter of several pieces
    keeps its largest; holes (A, R, O) are kept. The glyph sits in a picture with 4
    pixels of margin around its ink.
    """
    from PIL import Image, ImageDraw, ImageFont

    if not isinstance(letter, str) or len(letter) != 1 or letter.isspace():
        raise ValueError(f"letter must be one visible character, got {letter!r}.")
    if font is None:
        from matplotlib import font_manager

        font = font_manager.findfont("DejaVu Sans")
    face = ImageFont.truetype(str(font), size)
    left, top, right, bottom = face.getbbox(letter)
    pad = 4
    image = Image.new("L", (right - left + 2 * pad, bottom - top + 2 * pad), 0)
    ImageDraw.Draw(image).text((pad - left, pad - top), letter, fill=255, font=face)
    mask = np.asarray(image) > 127
    if not mask.any():
        raise ValueError(f"The font draws nothing for {letter!r}.")
    from skimage import measure

    count = measure.label(mask, connectivity=1, return_num=True)[1]
    return Shape.from_image(mask, component=0 if count > 1 else None, min_hole_area=4.0)


def glyph_handles(shape: Shape, heights=(0.08, 0.5, 0.92), min_width: float = 4.0) -> tuple:
    """Pins on a glyph (or any shape) at fractions `heights` of its height.

    For each height, the horizontal line there is cut by the shape into pieces (every
    stroke it crosses; pieces narrower than `min_width`, in the shape's units, are left
    out): a pin goes in the middle of each piece, or, where the line crosses a single
    piece, two pins go at a quarter and three quarters of it, so that every height holds
    its direction (an L's stem, an A's apex). Returns a tuple of `(k, 2)` arrays, one
    per height (bottom, middle and top by default); `np.concatenate` them for
    `Rig.build`.
    """
    x0, y0, x1, y1 = shape.bounds
    pins = []
    for h in heights:
        y = y0 + h * (y1 - y0)
        line = shapely.LineString([(x0 - 1.0, y), (x1 + 1.0, y)])
        cut = line.intersection(shape.polygon)
        pieces = sorted((g for g in getattr(cut, "geoms", [cut])
                         if g.geom_type == "LineString" and g.length >= min_width),
                        key=lambda g: g.bounds[0])
        at = (0.25, 0.75) if len(pieces) == 1 else (0.5,)
        pins.append(np.array([g.interpolate(f, normalized=True).coords[0] for g in pieces
                              for f in at], np.float64).reshape(-1, 2))
    if not any(len(p) for p in pins):
        raise ValueError(
            f"glyph_handles: no stroke at heights {tuple(heights)} is min_width={min_width:g} "
            f"wide or wider: the shape is {x1 - x0:.3g} wide and {y1 - y0:.3g} tall, and "
            f"min_width is in the shape's own units. Pass a smaller one for a small shape, "
            f"e.g. min_width={0.025 * (y1 - y0):.3g}.")
    return tuple(pins)
