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
# enough fixed-G steps to come near the minimum on limbs turned far, where the paper's
# 15 (`FixedG()`) stop visibly short of it (the fold suite measures how near).
DEFAULT_SOLVER = FixedG(iterations=100)
