"""Checks of the user's arrays at mvcjax's edges, with errors that name the argument,
what was wrong and the fix."""

from __future__ import annotations

import contextlib
import contextvars
import functools
import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

NOT_FINITE_TARGETS = "targets contain NaN or infinite values; give finite (x, y) targets."
_KINDS = {"c": "complex numbers", "b": "booleans", "U": "strings", "S": "bytes",
          "O": "Python objects", "M": "dates", "m": "time spans", "V": "records"}


def kind_of(array: np.ndarray) -> str:
    """What an array holds, in words."""
    return _KINDS.get(array.dtype.kind, array.dtype.name)


def as_points(points, name: str, rows: str = "n", *, allow_empty: bool = False) -> np.ndarray:
    """`(rows, 2)` real, finite float64 points, or a `TypeError`/`ValueError` naming `name`."""
    try:
        array = np.asarray(points)
    except ValueError:
        raise ValueError(f"{name} must be an array of shape ({rows}, 2) of (x, y) points; got a "
                         "ragged sequence.") from None
    if array.dtype.kind == "c":
        raise TypeError(f"{name} has complex coordinates: pass real (x, y) pairs, e.g. "
                        "np.stack([z.real, z.imag], axis=1).")
    if array.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real (x, y) numbers, got {kind_of(array)}; pass a "
                        f"float array of shape ({rows}, 2).")
    array = array.astype(np.float64)
    if array.ndim != 2 or array.shape[1] != 2 or (len(array) == 0 and not allow_empty):
        raise ValueError(f"{name} must be an array of shape ({rows}, 2) with at least one (x, y) "
                         f"point, got shape {array.shape}.")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite coordinates; give finite (x, y) "
                         "points.")
    return array


def as_array(value, name: str, what: str) -> np.ndarray:
    """`np.asarray(value)`, or a ValueError naming `name` where it is ragged (rows of
    different lengths), saying `what` it should be."""
    try:
        return np.asarray(value)
    except ValueError:
        raise ValueError(f"{name} must be {what}; got a ragged sequence (rows of different "
                         "lengths).") from None


# True while a program is traced whose inputs were checked on the host where they
# entered (`deform_frames`' per-frame solves; `Renderer.frames`' drawing, its tile
# budget counted first): their checks are left out. A check inside a compiled program is
# a host callback, and JAX's persistent compilation cache keeps no program that holds one.
_CHECKED_ON_ENTRY = contextvars.ContextVar("checked_on_entry", default=False)


@contextlib.contextmanager
def checked_on_entry():
    """Within: `check_when_run` checks nothing (what it checks was checked already)."""
    token = _CHECKED_ON_ENTRY.set(True)
    try:
        yield
    finally:
        _CHECKED_ON_ENTRY.reset(token)


def checks_left_out() -> bool:
    """Whether this is within `checked_on_entry` (a program traced here is one of its own)."""
    return _CHECKED_ON_ENTRY.get()


def check_when_run(array, failed, message: str):
    """`array`, raising `message` when the program runs if `failed` (traced) is true: the
    check that a concrete value gets on the host (none within `checked_on_entry`)."""
    if checks_left_out():
        return array
    return eqx.error_if(array, failed, message)


def finite_when_traced(array, message: str):
    """`array`, raising `message` when it is run if it holds a NaN or an infinity."""
    return check_when_run(array, ~jnp.all(jnp.isfinite(array)), message)


def is_whole_number(value) -> bool:
    """Whether `value` is a whole number: a Python or numpy int, not a bool (nor a float
    that happens to be whole)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_real_number(value) -> bool:
    """Whether `value` is a real number: a Python or numpy int or float, not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def whole_number(value, name: str, minimum: int = 1, what: str = "") -> int:
    """`value` as an int if it is a whole number (a Python or numpy int, not a bool or a
    float) of at least `minimum`: otherwise a TypeError for the type, a ValueError for
    the value, naming `name` (`what` says what it counts, e.g. " of frames")."""
    if not is_whole_number(value):
        raise TypeError(f"{name} must be a whole number{what} >= {minimum}, got {value!r}.")
    if value < minimum:
        raise ValueError(f"{name} must be a whole number{what} >= {minimum}, got {value!r}.")
    return int(value)


def refuse_removed(where: str, keywords, removed: dict[str, str]) -> None:
    """A TypeError if `keywords` holds one that `removed` maps to what to write now."""
    for key in keywords:
        if key in removed:
            raise TypeError(f"{where}: {key}= was removed; write {removed[key]}.")


def refusing_removed(**removed: str):
    """Decorator: calls with a keyword of `removed` raise `refuse_removed`'s error."""
    def wrap(function):
        @functools.wraps(function)
        def checked(*args, **kwargs):
            refuse_removed(f"{function.__qualname__}(...)", kwargs, removed)
            return function(*args, **kwargs)
        return checked
    return wrap


def refuse_string(name: str, value, objects: dict[str, str]) -> None:
    """A TypeError if `value` is a string that named an option before options were
    objects: `objects` maps each such string to the object to write now."""
    if isinstance(value, str) and value in objects:
        raise TypeError(f"{name}={value!r}: options are objects; write "
                        f"{name}={objects[value]}.")


def checked_option(name: str, value, kind: type, objects: dict[str, str], *,
                   described: str | None = None, default: str | None = None,
                   module: str = "mvcjax.advanced"):
    """`value` if it is a `kind` (an option object); otherwise a TypeError that says
    what to write: for a string that names one (a key of `objects`: an option's name
    from before options were objects, or a class's name), that object; for the class
    itself, an instance (of `module`, or of the class's `_MODULE`); for None, the
    `default` object, which leaving the option out gives. `described` lists what the
    option takes (by default, the objects)."""
    if isinstance(value, kind):
        return value
    fix, got = None, repr(value)
    if isinstance(value, str):
        fix, got = objects.get(value), f"the string {value!r} (options are objects)"
    elif isinstance(value, type) and issubclass(value, kind):
        fix = f"{getattr(value, '_MODULE', module)}.{value.__name__}()"
        got = f"the class {value.__name__}"
    elif value is None and default is not None:
        fix = f"{default} (the default: leave {name} out)"
    if len(got) > 80:  # an object of another library's, say: its package and class
        got = f"{type(value).__module__.split('.')[0]}'s {type(value).__name__}"
    described = described or " or ".join(dict.fromkeys(objects.values()))
    raise TypeError(f"{name} must be {described}, got {got}"
                    + (f"; write {name}={fix}." if fix else "."))


def as_devices(devices) -> list | None:
    """`devices` as a non-empty list of JAX devices, or None for the default device."""
    if devices is None:
        return None
    devices = list(devices) if isinstance(devices, (list, tuple)) else [devices]
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise ValueError(f"devices must be a non-empty list of JAX devices (e.g. "
                         f"jax.local_devices()), got {devices!r}; leave it out for the "
                         "default device.")
    return devices


def check_targets(targets, h: int, dtype) -> Array:
    """`(h, 2)` handle targets as `dtype`, or an error naming the problem: concrete targets
    (also when closed over inside jit) are checked on the host for their type, shape,
    finiteness and range; traced ones for their shape and type, and for their finiteness
    when they are run (`finite_when_traced`: under `jit` or `vmap`, NaN targets raise the
    same error instead of giving NaN vertices)."""
    traced = isinstance(targets, jax.core.Tracer)
    if not traced:
        host = as_array(targets, "targets", f"an array of shape ({h}, 2)")
        if host.dtype.kind not in "iuf":
            raise TypeError(f"targets must be real (x, y) numbers, got {kind_of(host)}; "
                            f"pass a float array of shape ({h}, 2).")
        if host.shape == (h, 2) and not np.all(np.isfinite(host)):
            raise ValueError(NOT_FINITE_TARGETS)
        with np.errstate(over="ignore"):
            representable = np.all(np.isfinite(host.astype(dtype)))
        if host.shape == (h, 2) and not representable:
            raise ValueError(
                f"targets reach {np.abs(host).max():.3g}, beyond {np.dtype(dtype).name}'s "
                f"range (the rig's precision): give targets in the shape's units, or "
                "build the rig with dtype=jnp.float64 (after "
                "jax.config.update('jax_enable_x64', True)).")
    targets = jnp.asarray(targets)
    if not jnp.issubdtype(targets.dtype, jnp.floating) and not jnp.issubdtype(
            targets.dtype, jnp.integer):
        raise TypeError(f"targets must be real (x, y) numbers, got {targets.dtype.name}.")
    if targets.shape != (h, 2):
        raise ValueError(
            f"targets must have shape ({h}, 2), one (x, y) per handle, got {targets.shape}; "
            "for several frames, use jax.vmap over a leading axis or mvcjax.deform_frames."
        )
    targets = targets.astype(dtype)
    return finite_when_traced(targets, NOT_FINITE_TARGETS) if traced else targets
