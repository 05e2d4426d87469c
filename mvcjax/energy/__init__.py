"""The energy (6) as data: stencils, terms, weights, and the factored global step."""

from ._energy import (
    NORMAL_WEIGHT as NORMAL_WEIGHT,
    Energy as Energy,
    Term as Term,
    Weights as Weights,
    as_rigid_as_possible as as_rigid_as_possible,
    check_shape_held as check_shape_held,
    check_weights as check_weights,
    handle_residual as handle_residual,
    laplacian_residual as laplacian_residual,
    length_residual as length_residual,
    mvc_residual as mvc_residual,
    residuals as residuals,
    rigid_alignment as rigid_alignment,
    rigid_start as rigid_start,
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
    as_factor_method as as_factor_method,
    dense_factor as dense_factor,
    local_blocks as local_blocks,
    local_stencil as local_stencil,
)
from ._stencils import (
    LAPLACIAN as LAPLACIAN,
    Blocks as Blocks,
    Stencil as Stencil,
    apply_stencils as apply_stencils,
    apply_stencils_transpose as apply_stencils_transpose,
    group_sum as group_sum,
    length_scale as length_scale,
    merge_blocks as merge_blocks,
    transpose_table as transpose_table,
)
