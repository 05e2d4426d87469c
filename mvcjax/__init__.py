"""mvcjax: fast, differentiable 2D shape deformation with mean value coordinates.

What a user poses, renders, exports and fits with (`__all__`); the rig's parts, the
options that only studies of the method need and the extension points are in
`mvcjax.advanced`.
"""

from . import (
    advanced as advanced,
    datasets as datasets,
    export as export,
    generate as generate,
    motion as motion,
)
from ._animation import deform_frames as deform_frames
from ._fit import fit_targets as fit_targets, image_loss as image_loss
from ._interact import Posing as Posing, interact as interact
from .character import Character as Character, load_layers as load_layers
from .energy import Weights as Weights
from .geometry import (
    Shape as Shape,
    cut_out as cut_out,
    flipped_triangles as flipped_triangles,
    image_mask as image_mask,
    load_image as load_image,
    pixels_to_points as pixels_to_points,
    points_to_pixels as points_to_pixels,
)
from .rendering import (
    Renderer as Renderer,
    depth_from_handles as depth_from_handles,
    fit_window as fit_window,
    render as render,
)
from .rig import (
    Bone as Bone,
    FullSolve as FullSolve,
    GivenControl as GivenControl,
    PaperControl as PaperControl,
    Rig as Rig,
    SizeLadder as SizeLadder,
)
from .solvers import (
    Dogleg as Dogleg,
    FixedG as FixedG,
    FoldFree as FoldFree,
    GaussNewton as GaussNewton,
    LevenbergMarquardt as LevenbergMarquardt,
)

__version__ = "0.1.0"

__all__ = [
    "Bone", "Character", "Dogleg", "FixedG", "FoldFree", "FullSolve", "GaussNewton",
    "GivenControl", "LevenbergMarquardt", "PaperControl", "Posing", "Renderer", "Rig",
    "Shape", "SizeLadder", "Weights", "advanced", "cut_out", "datasets", "deform_frames",
    "depth_from_handles", "export", "fit_targets", "fit_window", "flipped_triangles",
    "generate", "image_loss", "image_mask", "interact", "load_image", "load_layers", "motion",
    "pixels_to_points", "points_to_pixels", "render",
]


def __getattr__(name: str):
    """A name of `mvcjax.advanced` asked for here says where it is."""
    if not name.startswith("_") and hasattr(advanced, name):
        raise AttributeError(f"mvcjax.{name} is in mvcjax.advanced: write "
                             f"mvcjax.advanced.{name}.")
    raise AttributeError(f"module 'mvcjax' has no attribute {name!r}")
