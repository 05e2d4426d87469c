from ._base import (
    AbstractSolver as AbstractSolver,
    SkinnedMesh as SkinnedMesh,
    SolveInfo as SolveInfo,
    check_solver as check_solver,
)
from ._fixed_g import FixedG as FixedG
from ._fold_free import FoldFree as FoldFree
from ._jaxopt import (
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
)
from ._normal_cg import StructuredCG as StructuredCG
from ._optimistix import (
    Dogleg as Dogleg,
    GaussNewton as GaussNewton,
    LevenbergMarquardt as LevenbergMarquardt,
)

# What `Rig.solve` and `Rig.deform` run when no solver is given, from the turned start:
# on the default (as-rigid-as-possible) energy, as few fixed-G steps as come near its
# minimum on the fold suite's poses, to keep a frame within an interactive budget (the
# fold suite and `benchmarks/deform.py` measure both).
DEFAULT_SOLVER = FixedG(iterations=30)
