"""Built-in shapes: the horse, and the paper's character, flower and stick, each with
default handles and a drag; `model(name)` bundles them with their `Rig.build` options."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
import shapely
from shapely import affinity

from ._shape import Shape

if TYPE_CHECKING:
    from ._rig import Rig


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
    polygon keeps whole, however small `control_spacing` is.
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
        options: keyword arguments for `Rig.build` (`shape_spacing`,
            `control_spacing`, `margin`) that size the meshes like the paper's Table 1.
    """

    name: str
    shape: Shape
    handles: np.ndarray
    drag: np.ndarray
    options: dict = dataclasses.field(default_factory=dict)

    def rig(self, **overrides) -> Rig:
        """`Rig.build(shape, handles, **options)`, any option replaced by `overrides`
        (e.g. `dtype=jnp.float32`, `skinning="blended"`)."""
        # Imported here: loading the datasets should not pull in JAX, nor make a cycle
        # through the package's __init__, which imports this module first.
        from ._rig import Rig

        return Rig.build(self.shape, self.handles, **{**self.options, **overrides})


MODEL_NAMES = ("character", "flower", "stick", "horse")

# Spacings chosen so that the rigs come close to the paper's Table 1 (shape mesh
# vertices; control polygon + inner vertices): character 532; 32 + 34 (here 533;
# 37 + 33), flower 730; 44 + 76 (728; 59 + 66), stick 229; 24 + 19 (228; 28 + 12).
# The totals match within 7%; the split cannot: the control polygon's chords are at
# most `control_spacing` long while the inner vertices end up one to two spacings
# apart, so on limbs, stems and bars the polygon takes more of the vertices than the
# paper's did (even a disc only reaches the paper's ratio of about 1 : 1).
# The counts also rest on the control polygon keeping a long straight stretch of the
# offset outline as one edge (the character's limbs, the flower's stem).
_OPTIONS = {
    "character": dict(shape_spacing=6.75, control_spacing=19.0, margin=12.0),
    "flower": dict(shape_spacing=4.6, control_spacing=10.0, margin=6.5),
    "stick": dict(shape_spacing=7.63, control_spacing=21.0, margin=14.0),
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
    return Model(name, make_shape(), handles, drag, dict(_OPTIONS[name]))
