"""What a rig is made of, for those who extend mvcjax or study its method: the extension
points (control meshes, factors, skinnings, solvers), the rig's internal data, the
energy's terms as pure functions, the mean value coordinates themselves, and the jaxopt
solvers kept for comparison.

Posing, rendering, exporting and fitting need none of it: those live in `mvcjax`.
"""

from ._control import AbstractControl as AbstractControl
from ._coordinates import mean_value_coordinates as mean_value_coordinates
from ._energy import (
    Energy as Energy,
    Term as Term,
    as_rigid_as_possible as as_rigid_as_possible,
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
from ._handles import Handles as Handles
from ._rig import ControlMesh as ControlMesh, ShapeMesh as ShapeMesh
from ._skinning import AbstractSkinning as AbstractSkinning, Skinning as Skinning
from ._solvers import (
    AbstractSolver as AbstractSolver,
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
)
from ._solvers._normal_cg import StructuredCG as StructuredCG
from ._stencils import Stencil as Stencil
