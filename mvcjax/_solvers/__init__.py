from ._base import AbstractSolver as AbstractSolver, SolveInfo as SolveInfo
from ._fixed_g import FixedG as FixedG
from ._fold_free import FoldFree as FoldFree
from ._jaxopt import (
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
)
from ._optimistix import (
    Dogleg as Dogleg,
    GaussNewton as GaussNewton,
    LevenbergMarquardt as LevenbergMarquardt,
)

# What `Rig.solve` and `Rig.deform` run when no solver is given, from the turned start:
# enough fixed-G steps to come within a percent of the minimum's energy on the fold
# poses, where the paper's 15 (`FixedG()`) stop visibly short of it.
DEFAULT_SOLVER = FixedG(iterations=100)
