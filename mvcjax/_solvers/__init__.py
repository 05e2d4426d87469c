from ._base import AbstractSolver as AbstractSolver, SolveInfo as SolveInfo
from ._fixed_g import FixedG as FixedG
from ._jaxopt import (
    JaxoptGaussNewton as JaxoptGaussNewton,
    JaxoptLevenbergMarquardt as JaxoptLevenbergMarquardt,
)
from ._optimistix import (
    Dogleg as Dogleg,
    GaussNewton as GaussNewton,
    LevenbergMarquardt as LevenbergMarquardt,
)
