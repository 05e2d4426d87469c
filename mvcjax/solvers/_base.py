"""The interface every solver of the energy (6) shares."""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..core import checked_option, is_real_number, is_whole_number, refuse_removed
from ..energy import AbstractFactor, Energy
from ..geometry import Skinning


class SolveInfo(eqx.Module):
    """What a solve did.

    Attributes:
        converged: whether the solver met its tolerance (a fixed iteration count that
            did not is reported as not converged, not hidden).
        iterations: the number of steps taken.
        energy: the energy (6) at the returned control vertices, in the user's units
            (infinite where it exceeds the dtype's range; `converged` does not depend on
            that).
        inverted: how many control triangles the pose turned inside out (`FoldFree`
            keeps it at 0). The picture is the shape mesh, which can fold where no
            control triangle does and stay unfolded where one does:
            `mvcjax.flipped_triangles` counts its folds.
        handle_miss: the largest distance from a pinned point to its target, in the
            user's units: how far the pose is from what the handles ask (a `FoldFree`
            pose that would have to fold to reach them stops short, and this says by
            how much).

    A solver itself fills the first three; `Rig.solve` and `Rig.deform` add the last two.
    """

    converged: Bool[Array, ""]
    iterations: Int[Array, ""]
    energy: Float[Array, ""]
    inverted: Int[Array, ""] | None = None
    handle_miss: Float[Array, ""] | None = None

    def rescaled(self, scale) -> SolveInfo:
        """The info with the energy from the rig's frame to the user's units (times the
        frame's `scale` squared). Convergence was decided in the frame: a shape so large
        that its energy exceeds the dtype's range in its own units (float32's 3.4e38,
        which a posed shape a few 1e18 across can reach) keeps it, with an infinite
        `energy` that says so."""
        return dataclasses.replace(self, energy=self.energy * scale * scale)


class SkinnedMesh(eqx.Module):
    """The shape mesh as the control vertices carry it (`V_S = W V_C`, the rig's
    skinning): what a solver that watches the drawn shape needs.

    Attributes:
        faces: `(f, 3)` the shape mesh's counter-clockwise triangles.
        skinning: the rig's skinning (in the rig's frame, linear).
    """

    faces: Int[Array, "f 3"]
    skinning: Skinning

    def carry(self, y: Float[Array, "2 c"]) -> Float[Array, "2 n"]:
        """`W` applied to control coordinates, coordinate-major."""
        return jnp.einsum("nk,dnk->dn", self.skinning.weights, y[:, self.skinning.indices])


# The structured CG's options, once keywords of the least-squares solvers and FoldFree.
CG_KEYWORDS_REMOVED = {
    f"cg_{key}": f"linear_solver=mvcjax.advanced.StructuredCG({key}=...)"
    for key in ("steps", "rtol", "deflate")}


class AbstractSolver(eqx.Module):
    """A solver of the energy (6): a frozen configuration with one `solve` method.

    Its fields are static configuration: changing one compiles anew, while new targets
    or weights never do.
    """

    # Keywords the solver no longer takes, each with what to write now.
    _REMOVED: ClassVar[dict[str, str]] = {}
    # Where users find the solver.
    _MODULE: ClassVar[str] = "mvcjax"
    # How many frames `deform_frames` solves together (vmapped) by default.
    frames_together: ClassVar[int] = 1024

    def __new__(cls, *args, **kwargs):
        refuse_removed(f"{cls.__name__}(...)", kwargs, cls._REMOVED)
        return super().__new__(cls)

    @abc.abstractmethod
    def solve(
        self,
        energy: Energy,
        factor: AbstractFactor,
        targets: Float[Array, "h 2"],
        init: Float[Array, "n 2"],
    ) -> tuple[Float[Array, "n 2"], SolveInfo]:
        """Minimise the energy from `init`; return control vertices and a `SolveInfo`.

        Args:
            energy: the rig's energy data and weights.
            factor: the rig's precomputed global step (dense `G` or a sparse factor;
                solvers that do not need it ignore it).
            targets: `(h, 2)` handle targets.
            init: `(n, 2)` starting control vertices.
        """

    def solve_skinned(
        self,
        energy: Energy,
        factor: AbstractFactor,
        targets: Float[Array, "h 2"],
        init: Float[Array, "n 2"],
        shape: SkinnedMesh,
    ) -> tuple[Float[Array, "n 2"], SolveInfo]:
        """`solve`, told how the shape mesh follows the control vertices: what the rig
        calls. A solver that keeps an eye on the shape mesh (`FoldFree`) overrides it;
        the others solve the control mesh alone."""
        del shape
        return self.solve(energy, factor, targets, init)

    def fixed_steps(self, steps: int) -> AbstractSolver:
        """The same solver running exactly `steps` steps, its stopping test off: to time
        solvers over equal numbers of steps. Its `converged` is then no verdict: `FixedG`
        reports whether its tolerance held at the last step; the optimistix and jaxopt
        solvers, whose stopping test is what is turned off, report `False`."""
        raise NotImplementedError(f"{type(self).__name__} cannot run a fixed number of steps.")

    def history(
        self,
        energy: Energy,
        factor: AbstractFactor,
        targets: Float[Array, "h 2"],
        init: Float[Array, "n 2"],
        steps: int,
    ) -> Float[Array, " {steps+1}"]:
        """The energy at the start and after each of `steps` steps, stopping criteria
        ignored (for comparing solvers; `Rig.energy_history` is the public entry).

        A step is one iteration of the solver's own loop: one fixed-G step, or one
        optimistix or jaxopt step (which may be a rejected trial).
        """
        raise NotImplementedError(f"{type(self).__name__} does not record its history.")


def python_scalar(value):
    """A numpy scalar as the Python number it holds (static fields must hash and compare
    as plain values); anything else unchanged, for the checks to judge."""
    return value.item() if isinstance(value, (np.integer, np.floating)) else value


def checked_in_init(value):
    """An identity converter, for options whose `__check_init__` refuses a wrong value
    (a string where an object is wanted) with the spelling to write: equinox then
    leaves the argument unannotated, so that a runtime type checker does not answer
    first with a bare type error."""
    return value


def check_count(solver: eqx.Module, name: str, minimum: int = 1) -> None:
    """Refuse an option that must be a whole number (a Python or numpy int, not a bool
    or a float) of at least `minimum`: TypeError for the type, ValueError for the value."""
    value = getattr(solver, name)
    where = f"{type(solver).__name__}({name}={value!r})"
    if not is_whole_number(value):
        whole = isinstance(value, float) and value.is_integer() and value >= minimum
        raise TypeError(f"{where}: a whole number (int) >= {minimum} is needed, got "
                        f"{type(value).__name__}; write e.g. "
                        f"{name}={int(value) if whole else max(minimum, 1)}.")
    if value < minimum:
        raise ValueError(f"{where}: needs at least {minimum}.")


def check_tolerance(solver: eqx.Module, name: str, default: str = "") -> None:
    """Refuse a tolerance that is not a finite real number >= 0 (None means the default,
    where there is one): TypeError for the type, ValueError for the value."""
    value = getattr(solver, name)
    if value is None and default:
        return
    where = f"{type(solver).__name__}({name}={value!r})"
    fix = f" (or None for the default {default})" if default else ""
    if not is_real_number(value):
        raise TypeError(f"{where}: a tolerance must be a finite number >= 0{fix}, got "
                        f"{type(value).__name__}.")
    if not np.isfinite(value) or value < 0:
        raise ValueError(f"{where}: a tolerance must be a finite number >= 0{fix}.")


def converged_and_finite(converged: Array, vertices: Array, energy: Array) -> Array:
    """A solve converged only if its result is finite: a tolerance met at an infinite
    energy (a target at 1e20) is no convergence."""
    return converged & jnp.isfinite(energy) & jnp.all(jnp.isfinite(vertices))


def check_steps(solver: AbstractSolver, steps: Any) -> int:
    """`steps` for `fixed_steps`, refused unless a whole number >= 1."""
    where = f"{type(solver).__name__}.fixed_steps({steps!r})"
    if not is_whole_number(steps):
        raise TypeError(f"{where}: the number of steps must be a whole number (int) >= 1, got "
                        f"{type(steps).__name__}.")
    if steps < 1:
        raise ValueError(f"{where}: needs at least 1 step.")
    return int(steps)


def _solver_classes(base: type = AbstractSolver) -> dict[str, type]:
    """The public solver classes derived from `base`, by name."""
    found = {}
    for cls in base.__subclasses__():
        found |= _solver_classes(cls)
        if not cls.__name__.startswith("_"):
            found[cls.__name__] = cls
    return found


# Other names a solver is known by, each with the object to write.
_SOLVER_NICKNAMES = {
    **dict.fromkeys(("newton", "gauss-newton", "gauss_newton", "gn"), "mvcjax.GaussNewton()"),
    **dict.fromkeys(("levenberg-marquardt", "levenberg_marquardt", "lm"),
                    "mvcjax.LevenbergMarquardt()"),
    **dict.fromkeys(("fixed-g", "fixed_g", "local-global"), "mvcjax.FixedG()"),
    **dict.fromkeys(("fold-free", "fold_free"), "mvcjax.FoldFree()"),
}


def check_solver(solver, name: str = "solver"):
    """`solver` itself if it is an mvcjax solver object; otherwise a TypeError with the
    spelling that works (a solver's name as a string is a common slip)."""
    if isinstance(solver, AbstractSolver):  # every solve asks: the names only on refusal
        return solver
    return checked_option(
        name, solver, AbstractSolver,
        {**_SOLVER_NICKNAMES,
         **{k: f"{cls._MODULE}.{k}()" for k, cls in _solver_classes().items()}},
        described="an mvcjax solver object such as mvcjax.FixedG() or mvcjax.GaussNewton()")
