from ._base import AbstractSolver as AbstractSolver, SolveInfo as SolveInfo
from ._fixed_g import FixedG as FixedG
from ._optimistix import GaussNewton as GaussNewton, LevenbergMarquardt as LevenbergMarquardt
