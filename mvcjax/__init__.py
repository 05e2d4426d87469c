"""mvcjax: fast, differentiable 2D shape deformation with mean value coordinates.

What a user poses, renders, exports and fits with; the rig's parts and the extension
points are in `mvcjax.advanced`.
"""

from . import (
    advanced as advanced,
    datasets as datasets,
    export as export,
    generate as generate,
)
from ._animation import deform_frames as deform_frames
from ._character import Character as Character, CharacterRenderer as CharacterRenderer
from ._control import (
    FullSolve as FullSolve,
    GivenControl as GivenControl,
    PaperControl as PaperControl,
)
from ._energy import Weights as Weights
from ._fit import (
    FitResult as FitResult,
    fit_targets as fit_targets,
    image_loss as image_loss,
)
from ._handles import Bone as Bone
from ._image import cut_out as cut_out, image_mask as image_mask, load_image as load_image
from ._interact import Posing as Posing, interact as interact
from ._ladder import SizeLadder as SizeLadder
from ._layers import Layer as Layer, load_layers as load_layers
from ._metrics import (
    difference as difference,
    flipped_triangles as flipped_triangles,
    smoothness as smoothness,
)
from ._render import (
    Renderer as Renderer,
    checkerboard as checkerboard,
    core_depth as core_depth,
    depth_from_handles as depth_from_handles,
    fit_window as fit_window,
    render as render,
)
from ._rig import Rig as Rig
from ._shape import (
    Shape as Shape,
    pixels_to_points as pixels_to_points,
    points_to_pixels as points_to_pixels,
)
from ._skinning import (
    BarycentricSkinning as BarycentricSkinning,
    BlendedMVCSkinning as BlendedMVCSkinning,
    MVCSkinning as MVCSkinning,
)
from ._solvers import (
    Dogleg as Dogleg,
    FixedG as FixedG,
    FoldFree as FoldFree,
    GaussNewton as GaussNewton,
    LevenbergMarquardt as LevenbergMarquardt,
    SolveInfo as SolveInfo,
)

__version__ = "0.1.0"
