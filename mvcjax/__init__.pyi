"""What `import mvcjax` offers, loaded on first use (`lazy_loader.attach_stub` reads
these lines): the names, for readers and type checkers."""

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
