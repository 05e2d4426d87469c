"""mvcjax: fast, differentiable 2D shape deformation with mean value coordinates."""

from . import datasets as datasets, export as export
from ._control import (
    AbstractControl as AbstractControl,
    FullSolve as FullSolve,
    GivenControl as GivenControl,
    PaperControl as PaperControl,
)
from ._coordinates import mean_value_coordinates as mean_value_coordinates
from ._energy import (
    Energy as Energy,
    Weights as Weights,
    handle_residual as handle_residual,
    laplacian_residual as laplacian_residual,
    length_residual as length_residual,
    mvc_residual as mvc_residual,
    residuals as residuals,
    total_energy as total_energy,
)
from ._factor import (
    AbstractFactor as AbstractFactor,
    AbstractFactorMethod as AbstractFactorMethod,
    DenseFactor as DenseFactor,
    DenseG as DenseG,
    FactorBySize as FactorBySize,
    FactorSolver as FactorSolver,
    SparseFactor as SparseFactor,
    SparseLU as SparseLU,
)
from ._frames import deform_frames as deform_frames
from ._handles import Bone as Bone, Handles as Handles
from ._image import image_mask as image_mask, load_image as load_image
from ._interact import Posing as Posing, interact as interact
from ._metrics import (
    difference as difference,
    flipped_triangles as flipped_triangles,
    smoothness as smoothness,
)
from ._render import (
    Renderer as Renderer,
    checkerboard as checkerboard,
    depth_from_handles as depth_from_handles,
    fit_window as fit_window,
    render as render,
)
from ._rig import ControlMesh as ControlMesh, Rig as Rig, ShapeMesh as ShapeMesh
from ._shape import (
    Shape as Shape,
    pixels_to_points as pixels_to_points,
    points_to_pixels as points_to_pixels,
)
from ._skinning import (
    AbstractSkinning as AbstractSkinning,
    BarycentricSkinning as BarycentricSkinning,
    BlendedMVCSkinning as BlendedMVCSkinning,
    MVCSkinning as MVCSkinning,
    Skinning as Skinning,
)
from ._solvers import (
    AbstractSolver as AbstractSolver,
    Dogleg as Dogleg,
    FixedG as FixedG,
    FoldFree as FoldFree,
    GaussNewton as GaussNewton,
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
    LevenbergMarquardt as LevenbergMarquardt,
    SolveInfo as SolveInfo,
)

# isort: split
# Fitting to a picture (issue 17), kept last so that it merges cleanly.
from ._fit import (
    FitResult as FitResult,
    fit_targets as fit_targets,
    image_loss as image_loss,
)

__version__ = "0.1.0"
