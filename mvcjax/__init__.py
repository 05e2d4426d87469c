"""mvcjax: fast, differentiable 2D shape deformation with mean value coordinates.

What a user poses, renders, exports and fits with; the rig's parts and the extension
points are in `mvcjax.advanced`.
"""

from . import advanced as advanced, datasets as datasets, export as export, generate as generate
from ._animation import deform_frames as deform_frames
from ._fit import FitResult as FitResult, fit_targets as fit_targets, image_loss as image_loss
from ._interact import Posing as Posing, interact as interact
from .character import (
    Character as Character,
    CharacterRenderer as CharacterRenderer,
    Layer as Layer,
    load_layers as load_layers,
)
from .energy import Weights as Weights
from .geometry import (
    BarycentricSkinning as BarycentricSkinning,
    BlendedMVCSkinning as BlendedMVCSkinning,
    MVCSkinning as MVCSkinning,
    Shape as Shape,
    cut_out as cut_out,
    difference as difference,
    flipped_triangles as flipped_triangles,
    image_mask as image_mask,
    load_image as load_image,
    pixels_to_points as pixels_to_points,
    points_to_pixels as points_to_pixels,
    smoothness as smoothness,
)
from .render import (
    Renderer as Renderer,
    checkerboard as checkerboard,
    core_depth as core_depth,
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
    SolveInfo as SolveInfo,
)

__version__ = "0.1.0"
