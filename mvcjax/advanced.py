"""What a rig is made of, for those who extend mvcjax or study its method: the extension
points (control meshes, factors, skinnings, solvers, starts, `AbstractRig`: what a rig
and a character both offer), the option objects (a start, a grown window, a fill, where
a drawn edge comes from, what a fit compares, a background's colour), the rig's
internal data, the energy's terms as pure functions, the mean value coordinates
themselves, the jaxopt solvers kept for comparison, the
paper's skinning options, the types results come in (`SolveInfo`, `FitResult`,
`CharacterRenderer`, `Layer`) and the metrics and textures the benchmarks use.

Posing, rendering, exporting and fitting need none of it: those live in `mvcjax`.
"""

from ._fit import (
    AbstractChannels as AbstractChannels,
    AlphaChannel as AlphaChannel,
    FitResult as FitResult,
    RGBAChannels as RGBAChannels,
)
from .character import CharacterRenderer as CharacterRenderer, Layer as Layer
from .energy import (
    AbstractFactor as AbstractFactor,
    AbstractFactorMethod as AbstractFactorMethod,
    DenseFactor as DenseFactor,
    DenseG as DenseG,
    Energy as Energy,
    FactorBySize as FactorBySize,
    FactorSolver as FactorSolver,
    SparseFactor as SparseFactor,
    SparseLU as SparseLU,
    Stencil as Stencil,
    Term as Term,
    as_rigid_as_possible as as_rigid_as_possible,
    handle_residual as handle_residual,
    laplacian_residual as laplacian_residual,
    length_residual as length_residual,
    mvc_residual as mvc_residual,
    residuals as residuals,
    total_energy as total_energy,
)
from .geometry import (
    AbstractSkinning as AbstractSkinning,
    BarycentricSkinning as BarycentricSkinning,
    BlendedMVCSkinning as BlendedMVCSkinning,
    CornerColour as CornerColour,
    MVCSkinning as MVCSkinning,
    Skinning as Skinning,
    difference as difference,
    mean_value_coordinates as mean_value_coordinates,
    smoothness as smoothness,
)
from .rendering import (
    AbstractAlpha as AbstractAlpha,
    Checkerboard as Checkerboard,
    GrownWindow as GrownWindow,
    MeshAlpha as MeshAlpha,
    PictureAlpha as PictureAlpha,
    core_depth as core_depth,
)
from .rig import (
    AbstractControl as AbstractControl,
    AbstractRig as AbstractRig,
    AbstractStart as AbstractStart,
    ControlMesh as ControlMesh,
    Handles as Handles,
    RestStart as RestStart,
    RigidStart as RigidStart,
    ShapeMesh as ShapeMesh,
    TurnedStart as TurnedStart,
)
from .solvers import (
    AbstractSolver as AbstractSolver,
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
    SolveInfo as SolveInfo,
    StructuredCG as StructuredCG,
)
