"""Fit a deformation to a picture: handle targets whose rendered pose matches a target
picture, by least squares on the pixels.

The loss compares the pose `rig.deform(targets)`, drawn by the renderer, with the
picture, pixel by pixel. Which triangle a pixel shows is decided without gradients
(`_render.py`); the gradients come from the shading: a textured interior moves its
texture under the pixels, and the antialiased boundary edges cover a pixel by a linear
ramp of its centre's distance to the edge, so that the silhouette moves the coverage of
the pixels it crosses. That ramp is one pixel wide: the sharp loss is kinked at every
pixel, and flat where moving a part changes nothing it counts (a thin part that no
longer overlaps its place in the target). Blurring both pictures with a Gaussian of
`blur` pixels spreads every edge over a few `blur`s, so the slopes overlap and reach
that far; the fit runs from a wide blur down to none (coarse to fine)."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from .core import checked_option, compiled_by, kind_of, whole_number
from .rendering import Renderer, as_picture, check_drawn_mesh, in_window
from .rig import AbstractRig
from .solvers import DEFAULT_SOLVER, AbstractSolver, check_solver


class AbstractChannels(eqx.Module):
    """What `image_loss` and `fit_targets` compare (`channels=`): `RGBAChannels()` or
    `AlphaChannel()`.

    Attributes:
        weights: the weight of each premultiplied channel (R, G, B, A) in the loss.
        takes_mask: whether a `(rows, cols)` mask is a picture to compare with.
    """

    weights: ClassVar[tuple[float, float, float, float]]
    takes_mask: ClassVar[bool]


class RGBAChannels(AbstractChannels):
    """Premultiplied colour and alpha: the picture as it is drawn. The default."""

    weights: ClassVar[tuple[float, float, float, float]] = (1.0, 1.0, 1.0, 1.0)
    takes_mask: ClassVar[bool] = False


class AlphaChannel(AbstractChannels):
    """Coverage only: silhouettes, against an RGBA picture's alpha or a `(rows, cols)`
    mask."""

    weights: ClassVar[tuple[float, float, float, float]] = (0.0, 0.0, 0.0, 1.0)
    takes_mask: ClassVar[bool] = True



class FitResult(eqx.Module):
    """What `fit_targets` found.

    Attributes:
        targets: `(h, 2)` the fitted handle targets, in the plane's coordinates.
        loss_history: `(stages, steps)` the loss (`image_loss` at that stage's blur)
            after each step of each stage, at the targets the step accepted (the first
            step of a stage evaluates its start: its loss is the start's); NaN after the
            stage stopped.
        blurs: `(stages,)` the blur of each stage, in pixels.
        steps: `(stages,)` how many steps each stage took.
        converged: `(stages,)` whether each stage met the solver's tolerances before its
            step limit. The fit converged when its last stage did (`fit_converged`).
    """

    targets: Float[Array, "h 2"]
    loss_history: Float[Array, "stages steps"]
    blurs: Float[Array, " stages"]
    steps: Int[Array, " stages"]
    converged: Bool[Array, " stages"]

    @property
    def loss(self) -> Float[Array, ""]:
        """The final loss (of the last stage, at its blur)."""
        return self.loss_history[-1, self.steps[-1] - 1]

    @property
    def fit_converged(self) -> Bool[Array, ""]:
        """Whether the last stage (the finest blur) converged."""
        return self.converged[-1]


# ---- checks ---------------------------------------------------------------------------


def _check_channels(channels) -> AbstractChannels:
    return checked_option("channels", channels, AbstractChannels,
                          {"rgba": "mvcjax.advanced.RGBAChannels()",
                           "alpha": "mvcjax.advanced.AlphaChannel()"})


def _check_pair(rig, renderer) -> Renderer:
    """The renderer of `rig`'s whole shape mesh (a character's parts joined, in its draw
    order), or an error naming what to pass."""
    if not isinstance(rig, AbstractRig):
        raise TypeError(f"rig must be an mvcjax.Rig or an mvcjax.Character, got "
                        f"{type(rig).__name__}.")
    drawn = getattr(renderer, "mesh", None)
    if not isinstance(drawn, Renderer):
        raise TypeError(f"renderer must be an mvcjax.Renderer (Renderer.build(rig, ...), or "
                        f"Renderer.build(character, layers)), got {type(renderer).__name__}.")
    check_drawn_mesh(drawn, rig.shape_mesh.vertices, rig.shape_mesh.faces)
    return drawn


def _check_solver(solver) -> AbstractSolver:
    return DEFAULT_SOLVER if solver is None else check_solver(solver)


def _check_blurs(blurs) -> np.ndarray:
    """`(stages,)` the stages' blurs as float64 numbers, or an error: one or more finite
    numbers >= 0."""
    try:
        blur_values = np.atleast_1d(np.asarray(blurs, np.float64))
    except (TypeError, ValueError):
        blur_values = np.array([np.nan])
    if blur_values.ndim != 1 or not np.all(np.isfinite(blur_values)) or np.any(
            blur_values < 0):
        raise ValueError(f"blurs must be one or more numbers >= 0 (pixels, one per stage), "
                         f"got {blurs!r}.")
    return blur_values


def _check_method(method, rtol, atol) -> optx.AbstractGaussNewton:
    """The fit's least-squares solver: `method`, by default
    `optx.LevenbergMarquardt(rtol, atol)`, or an error if it is not Gauss-Newton-type."""
    if method is None:
        method = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    if not isinstance(method, optx.AbstractGaussNewton):
        raise TypeError(f"method must be an optimistix Gauss-Newton-type solver such as "
                        f"optx.LevenbergMarquardt(rtol, atol), got {method!r}.")
    return method


def _check_in_view(rig, renderer, targets) -> None:
    """Raise if no handle lies in the renderer's window, warn about those outside."""
    window = np.asarray(renderer.window, np.float64)
    points = np.asarray(targets, np.float64)
    inside = in_window(points, window)
    hint = ("widen the window, e.g. mvcjax.Renderer.build(rig, ..., "
            "window=mvcjax.fit_window(rig.shape_mesh.vertices, size)), or start nearer")
    if not inside.any():
        raise ValueError(f"no handle of the rig lies in the renderer's window {window.tolist()} "
                         f"(the starting targets span {points.min(0).tolist()} to "
                         f"{points.max(0).tolist()}): the fit cannot see them; {hint}.")
    if not inside.all():
        warnings.warn(f"handles {np.flatnonzero(~inside).tolist()} lie outside the "
                      f"renderer's window {window.tolist()}: the fit may not see where they "
                      f"go; {hint}.", stacklevel=3)


def _prepare_picture(picture, renderer: Renderer, channels: AbstractChannels) -> Array:
    """The target as the loss compares it: `(rows, cols, 4)` premultiplied RGBA (a mask
    is its alpha, black), in the renderer's dtype. Concrete pictures may be anything
    `load_image` reads (alpha: also a `(rows, cols)` mask); traced ones must already be
    floats in [0, 1] of that shape (or `(rows, cols, 4)`)."""
    rows, cols = renderer.shape
    dtype = renderer.window.dtype
    if isinstance(picture, jax.core.Tracer):
        array = picture
    elif channels.takes_mask and not isinstance(picture, str) and np.ndim(picture) == 2:
        array = np.asarray(picture)
        if array.dtype.kind not in "biuf":
            raise TypeError(f"picture must be a mask of numbers or booleans, got "
                            f"{kind_of(array)}.")
        if array.dtype.kind in "iu":
            array = array / np.iinfo(array.dtype).max
        array = array.astype(np.float64)
        if not np.all(np.isfinite(array)) or array.min() < 0 or array.max() > 1:
            raise ValueError("picture (a mask) must hold values in [0, 1] (coverage), or "
                             "booleans.")
    else:
        if (channels.takes_mask and not isinstance(picture, str)
                and np.ndim(picture) == 3 and np.shape(picture)[2] == 3):
            raise ValueError("picture is RGB, which has no alpha to compare silhouettes "
                             "with: pass a (rows, cols) mask, an RGBA picture, or use "
                             "channels=mvcjax.advanced.RGBAChannels().")
        array = as_picture(picture, "picture")
    shape = tuple(array.shape)
    if shape[:2] != (rows, cols):
        raise ValueError(f"picture is {shape[0]} x {shape[1]} pixels (rows x cols) but the "
                         f"renderer draws {rows} x {cols} (renderer.shape): resize the "
                         f"picture, or build the renderer with size={shape[:2]}.")
    if array.ndim == 2:
        if not channels.takes_mask:
            raise ValueError(f"picture of shape {shape} is a mask: compare silhouettes with "
                             "channels=mvcjax.advanced.AlphaChannel(), or pass (rows, cols, "
                             "4) RGBA.")
        mask = jnp.asarray(array, dtype)[..., None]
        return jnp.concatenate([jnp.zeros_like(mask)] * 3 + [mask], axis=-1)
    if array.ndim != 3 or shape[2] != 4:
        raise ValueError(f"picture must be ({rows}, {cols}, 4) straight RGBA (or a "
                         f"({rows}, {cols}) mask with channels=AlphaChannel()), got shape "
                         f"{shape}.")
    array = jnp.asarray(array, dtype)
    return _premultiplied(array)


# ---- the loss ---------------------------------------------------------------------------


def _premultiplied(rgba):
    return jnp.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1)


def _gaussian_matrix(n: int, blur, dtype):
    """`(n, n)` the Gaussian of `blur` pixels along one axis, as a matrix (identity at
    0). Outside the picture counts as transparent (the weights are normalised by the
    whole kernel, not by the part inside), as the renderer's background is."""
    offsets = jnp.arange(n, dtype=dtype)
    d = offsets[:, None] - offsets[None, :]
    blur = jnp.asarray(blur, dtype)
    sharp = blur <= 0
    sigma = jnp.where(sharp, 1.0, blur)
    # The kernel's sum over all the offsets it can reach (2n - 1 of them).
    reach = jnp.arange(-(n - 1), n, dtype=dtype)
    total = jnp.sum(jnp.exp(-0.5 * (reach / sigma) ** 2))
    kernel = jnp.exp(-0.5 * (d / sigma) ** 2) / total
    return jnp.where(sharp, jnp.eye(n, dtype=dtype), kernel)


def _blurred(picture, blur):
    """`picture` (`(rows, cols)` or `(rows, cols, c)`) blurred by a Gaussian of `blur`
    pixels. Two matrix products: any blur is a number, so changing it never recompiles,
    and the cost (`rows * cols * (rows + cols)`) is small beside the render's."""
    rows, cols = picture.shape[:2]
    down = _gaussian_matrix(rows, blur, picture.dtype)
    across = _gaussian_matrix(cols, blur, picture.dtype)
    return jnp.einsum("ij,jk...,lk->il...", down, picture, across)


def _weights(channels: AbstractChannels, dtype):
    """The weight of each premultiplied channel in the loss. An array, not a choice of
    program: a silhouette fit and a colour fit of the same sizes share one compilation
    (the zero colour residuals of a silhouette cost little beside the render)."""
    return jnp.asarray(channels.weights, dtype)


def _residuals(rig, renderer, solver, weights, targets, target_picture, blur):
    # In the picture's window, given (`_check_in_view` warned of handles outside it).
    drawn = _premultiplied(renderer(rig.joined(rig.deform(targets, solver)), renderer.window))
    # Per pixel and channel, unscaled: the solver's damping and tolerances then meet
    # numbers of order one, whatever the picture's size. Blurring is linear, so
    # blurring the difference is the difference of the blurred pictures.
    return _blurred((drawn - target_picture) * weights, blur).ravel()


def image_loss(
    rig: AbstractRig,
    renderer: Any,
    targets: Real[ArrayLike, "h 2"],
    picture: Any,
    *,
    channels: AbstractChannels | str = RGBAChannels(),  # a string: refused, naming the object
    blur: Real[ArrayLike, ""] = 0.0,
    solver: Any = None,
) -> Float[Array, ""]:
    """How far the rig's pose at `targets`, drawn by `renderer`, is from `picture`: the
    mean squared difference over pixels (and channels) of the two pictures, both blurred.

    Pure JAX: jit it, and differentiate it with respect to `targets` (forward or reverse
    mode), the picture or `blur`. Targets, picture values and `blur` are numbers: changing
    them never recompiles.

    Args:
        rig: the `Rig` to pose, or a `Character` (with its `CharacterRenderer`).
        renderer: a `Renderer` built for this rig (`Renderer.build(rig, ...)`); its
            `shape` is the pictures' size and its window the part of the plane compared.
        targets: `(h, 2)` handle targets (`rig.handle_positions` is the rest pose).
        picture: the target picture, `renderer.shape` = `(rows, cols)` pixels: straight
            RGBA `(rows, cols, 4)` (RGB `(rows, cols, 3)` is opaque; outside `jit` also
            integers, a grey picture or a file path, as `load_image` reads), or with
            `channels=AlphaChannel()` a `(rows, cols)` mask of coverage in [0, 1].
            Inside a transformation it must be floats in [0, 1] of shape
            `(rows, cols, 4)`, or `(rows, cols)` for `AlphaChannel()`.
        channels: what is compared (in `mvcjax.advanced`): `RGBAChannels()` (default)
            premultiplied colour and alpha; `AlphaChannel()` silhouettes (coverage)
            only.
        blur: the standard deviation, in pixels, of a Gaussian blur of both pictures
            (0: none). A wider blur lets the gradient see a silhouette or a texture
            further away than the one-pixel antialiased edge.
        solver: the deformation's solver, as in `rig.deform` (default: `rig.deform`'s).

    Returns:
        The scalar loss, in the renderer's dtype.
    """
    renderer = _check_pair(rig, renderer)
    channels = _check_channels(channels)
    solver = _check_solver(solver)
    target_picture = _prepare_picture(picture, renderer, channels)
    weights = _weights(channels, target_picture.dtype)
    residuals = _residuals(rig, renderer, solver, weights, rig._check_targets(targets),
                           target_picture, blur)
    # The mean over the pixels and the channels compared.
    return jnp.sum(residuals**2) / (target_picture[..., 0].size * jnp.sum(weights))


# ---- the fit ----------------------------------------------------------------------------


def _with_explicit_jacobian(f, y):
    """`f(y)` (a vector of `m` residuals of few unknowns `y`), whose forward-mode
    derivative is a product with the Jacobian, computed once (`len(y)` tangents of one
    linearisation). Optimistix linearises the residuals, materialises the Jacobian and
    transposes the linearisation for the gradient: through the renderer that compiled
    its reverse pass as well, which lengthened compilation; through this, the
    transpose is a matrix product."""

    @jax.custom_jvp
    def explicit(y):
        return f(y)

    @explicit.defjvp
    def _(primals, tangents):
        (y,), (t,) = primals, tangents
        r, linear = jax.linearize(f, y)
        basis = jnp.eye(y.size, dtype=y.dtype).reshape(y.size, *y.shape)
        jacobian = jax.vmap(linear)(basis)  # (len(y), m)
        return r, t.reshape(-1) @ jacobian

    return explicit(y)


def _targets_at(start, offsets, pixel, bone_rows, bone_lengths):
    """The targets for the unknowns `offsets` (pixels): each target moved from `start`;
    for a rigid bone, its start row moved (the pivot) and its end row's first unknown an
    arc, in pixels, that the bone turns through about the pivot (its second unknown is
    unused): a bone's pose fixes its targets, so the fit's answer is unique."""
    targets = start + offsets * pixel
    size = jnp.mean(pixel)
    for (first, last), length in zip(bone_rows, bone_lengths):
        pivot = targets[first]
        along = start[last] - start[first]
        angle = jnp.arctan2(along[1], along[0]) + offsets[last, 0] * size / length
        targets = targets.at[last].set(
            pivot + length * jnp.stack([jnp.cos(angle), jnp.sin(angle)]).astype(pivot.dtype))
    return targets


@compiled_by()
def _stage(rig, renderer, solver, weights, method, steps: int, start, target_picture, blur,
           pixel, bone_rows, bone_lengths):
    """One stage of the fit: up to `steps` steps of `method` at one blur, from `start`.

    The unknowns are the targets' offsets from `start` in pixels, so that the solver's
    tolerances and damping are in pixels whatever the plane's units. `blur` is a number:
    every stage of a fit runs the same compiled program."""

    # The solver's arithmetic runs in JAX's default float (float64 with x64 on), as
    # optimistix's own step sizes do: a float32 fit under x64 would otherwise mix the two.
    dtype = jnp.promote_types(start.dtype, jnp.asarray(1.0).dtype)

    def residuals(offsets):
        targets = _targets_at(start, offsets, pixel, bone_rows, bone_lengths).astype(
            start.dtype)
        r = _residuals(rig, renderer, solver, weights, targets, target_picture, blur)
        return r.astype(dtype)

    count = target_picture[..., 0].size * jnp.sum(weights)

    def fn(offsets, _):
        # The loss rides along as the residuals' aux, so the history costs no render.
        r = _with_explicit_jacobian(residuals, offsets)
        return r, jnp.sum(r**2) / count

    y0 = jnp.zeros(start.shape, dtype)
    options, tags = {}, frozenset()
    f_struct, aux_struct = jax.eval_shape(fn, y0, None)
    state = method.init(fn, y0, None, options, f_struct, aux_struct, tags)
    history = jnp.full(steps, jnp.asarray(jnp.nan, dtype))

    # The solver's state holds the Jacobian's jaxpr, not an array: the loop carries the
    # arrays, and the rest (the same every step) is put back around them.
    dynamic, static = eqx.partition(state, eqx.is_array)

    def going(carry):
        step, _, dynamic, _ = carry
        done, _ = method.terminate(fn, y0, None, options, eqx.combine(dynamic, static), tags)
        return (step < steps) & ~done

    def advance(carry):
        step, y, dynamic, history = carry
        y, state, loss = method.step(fn, y, None, options, eqx.combine(dynamic, static), tags)
        # A step returns the aux of the point it started from, the one the step before
        # accepted (the first step evaluates the start and accepts it): the history's
        # previous entry. The last is filled after the loop.
        return (step + 1, y, eqx.filter(state, eqx.is_array),
                history.at[jnp.maximum(step - 1, 0)].set(loss))

    step, y, dynamic, history = jax.lax.while_loop(
        going, advance, (jnp.asarray(0), y0, dynamic, history))
    history = history.at[jnp.maximum(step - 1, 0)].set(fn(y, None)[1])
    state = eqx.combine(dynamic, static)
    done, result = method.terminate(fn, y, None, options, state, tags)
    converged = done & (result == optx.RESULTS.successful)
    found = _targets_at(start, y, pixel, bone_rows, bone_lengths).astype(start.dtype)
    return found, history.astype(start.dtype), step, converged


def _tolerances_as_arrays(method):
    """`method` with its tolerances as arrays: numbers of the compiled program, not
    constants of it, so that other tolerances never recompile."""
    return eqx.tree_at(lambda m: (m.rtol, m.atol), method,
                       (jnp.asarray(method.rtol), jnp.asarray(method.atol)))


def _pixel_size(renderer, dtype):
    """`(2,)` a pixel's width and height in the plane's coordinates."""
    rows, cols = renderer.shape
    window = jnp.asarray(renderer.window, dtype)
    return jnp.stack([(window[2] - window[0]) / cols, (window[3] - window[1]) / rows])


def _fit_stages(rig, renderer, solver, weights, method, steps: int, start, target_picture,
                blur_values) -> FitResult:
    """The fit's stages in turn, one per blur, each from the targets the last found:
    the `FitResult` of them all."""
    pixel = _pixel_size(renderer, start.dtype)
    # Rigid bones by pivot and angle: their rows fix the program, their lengths do not.
    bones = rig.handles.rigid_bones(rig.handle_positions)
    bone_rows = tuple((first, last) for first, last, _ in bones)
    bone_lengths = jnp.asarray([length for *_, length in bones], start.dtype)
    targets, histories, counts, converged = start, [], [], []
    for blur in blur_values:
        targets, history, count, done = _stage(
            rig, renderer, solver, weights, method, steps, targets, target_picture,
            jnp.asarray(blur, start.dtype), pixel, bone_rows, bone_lengths)
        histories.append(history)
        counts.append(count)
        converged.append(done)
    return FitResult(targets=targets, loss_history=jnp.stack(histories),
                     blurs=jnp.asarray(blur_values, start.dtype), steps=jnp.stack(counts),
                     converged=jnp.stack(converged))


def fit_targets(
    rig: AbstractRig,
    renderer: Any,
    picture: Any,
    *,
    init: Real[ArrayLike, "h 2"] | None = None,
    channels: AbstractChannels | str = RGBAChannels(),  # a string: refused, naming the object
    blurs: Any = (4.0, 2.0, 1.0, 0.0),
    steps: Any = 30,
    rtol: float = 1e-4,
    atol: float = 1e-4,
    method: Any = None,
    solver: Any = None,
    warn: bool = True,
) -> FitResult:
    """Handle targets whose pose, drawn by `renderer`, matches `picture`: a least-squares
    fit of the pixels (`image_loss`), by optimistix's Levenberg-Marquardt from `init`,
    one stage per blur, from the widest blur to the last (coarse to fine).

    A rigid bone is fitted by its pivot (its start) and its angle, at its rest length:
    its pose fixes them, so the targets found are the pose's (its two targets come back
    exactly its length apart). A stretchy bone's ends are fitted as two points.

    Each step builds the Jacobian of the pixel residuals with respect to the `2h` target
    coordinates by forward mode (`2h` tangents, one render), so a step costs a few
    renders. Only `steps`, the sizes, the dtypes and the kinds of solver compile: every
    stage, picture, start, tolerance and choice of `channels` runs the same program.

    Args:
        rig: the `Rig` to pose, or a `Character` (with its `CharacterRenderer`).
        renderer: a `Renderer` built for this rig whose window holds the handles (the
            fit sees only what it draws: `mvcjax.fit_window` makes a window that holds a
            pose, or an animation's poses).
        picture: the target picture, `renderer.shape` pixels: see `image_loss`.
        init: `(h, 2)` the starting targets; default the rest pose,
            `rig.handle_positions`.
        channels: `RGBAChannels()` (colour) or `AlphaChannel()` (silhouette only), as in
            `image_loss`.
        blurs: the standard deviation of each stage's Gaussian blur, in pixels, e.g.
            `(4.0, 2.0, 1.0, 0.0)`: the first about as wide as the largest move to
            recover (half of it worked on the horse), the last 0 for a sharp fit.
        steps: the most solver steps per stage (static: another value compiles anew).
        rtol: the solver's relative tolerance (optimistix's Cauchy criterion: a stage
            converged when successive targets, in pixels, and residuals agree to
            `atol + rtol * size`). Numbers: other tolerances do not recompile.
        atol: the solver's absolute tolerance, in pixels for the targets and in
            picture values for the residuals.
        method: an optimistix Gauss-Newton-type least-squares solver
            (`optx.LevenbergMarquardt`, `optx.GaussNewton`, `optx.Dogleg`); it overrides
            `rtol` and `atol`. Default `optx.LevenbergMarquardt(rtol, atol)`.
        solver: the deformation's solver, as in `rig.deform` (default: `rig.deform`'s,
            a fixed loop that forward mode differentiates). The targets found are right
            for this solver's deformation.
        warn: warn (`RuntimeWarning`) if the last stage did not converge.

    Returns:
        A `FitResult`: the targets, the loss at every step, and whether each stage
        converged.
    """
    renderer = _check_pair(rig, renderer)
    channels = _check_channels(channels)
    solver = _check_solver(solver)
    steps = whole_number(steps, "steps", what=" (the most solver steps per stage)")
    blur_values = _check_blurs(blurs)
    method = _tolerances_as_arrays(_check_method(method, rtol, atol))
    start = rig._check_targets(rig.handle_positions if init is None else init)
    _check_in_view(rig, renderer, start)
    target_picture = _prepare_picture(picture, renderer, channels)
    result = _fit_stages(rig, renderer, solver, _weights(channels, target_picture.dtype),
                         method, int(steps), start, target_picture, blur_values)
    if warn and not bool(result.fit_converged):
        warnings.warn(f"fit_targets: the last stage (blur {blur_values[-1]:g}) did not "
                      f"converge in {steps} steps (loss {float(result.loss):.3g}); the "
                      "targets are the last iterate. Allow more steps=, loosen rtol/atol, "
                      "or start nearer (init=).", RuntimeWarning, stacklevel=2)
    return result
