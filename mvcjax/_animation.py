"""Many frames at once: the deformation over a batch of targets, in chunks, and sharded
over devices."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import Array, Float

from .core import (
    NOT_FINITE_TARGETS,
    as_array,
    as_devices,
    checked_on_entry,
    compiled_by,
    finite_when_traced,
    kind_of,
    to_device,
    whole_number,
)
from .geometry import skin_frames_into
from .rig import AbstractRig, Rig, padded_twin
from .solvers import DEFAULT_SOLVER, AbstractSolver, check_solver


def _pad_frames(targets, multiple: int):
    """`targets` with the last frame repeated up to a multiple of `multiple` frames (the
    copies are dropped from the result)."""
    frames = targets.shape[0]
    padded = -(-frames // multiple) * multiple
    if padded == frames:
        return targets
    return jnp.concatenate([targets, jnp.repeat(targets[-1:], padded - frames, 0)])


def _solve_chunked(rig: AbstractRig, targets, solver: AbstractSolver, chunk: int):
    """Control vertices (the rig's own: a character's a tuple of parts), `chunk` frames
    at a time, each chunk a vmap of the single frame's solve (the solver's batching
    rule)."""
    frames = targets.shape[0]
    chunk = min(chunk, frames)
    targets = _pad_frames(targets, chunk)
    with checked_on_entry():  # by `_checked_frames`
        control = jax.lax.map(jax.vmap(lambda t: rig.solve(t, solver)),
                              targets.reshape(-1, chunk, *targets.shape[1:]))
    return jax.tree.map(lambda c: c.reshape(-1, *c.shape[2:])[:frames], control)


def _solve_in_sequence(rig: AbstractRig, targets, solver: AbstractSolver):
    """Control vertices, frame after frame, each solved from the pose before it (the
    first from its turned start)."""
    def step(previous, t):
        control = rig.solve(t, solver, init=previous)
        return rig.joined(control), control

    with checked_on_entry():  # the frames by `_checked_frames`, each start a solve's pose
        return jax.lax.scan(step, rig.start(targets[0]), targets)[1]


def _deform_chunked(rig: AbstractRig, targets, solver: AbstractSolver, chunk: int,
                    warm_start: bool = False):
    # The skinning maps over all frames at once (its rule takes them a few at a time),
    # writing the result in place: skinning inside each chunk would copy every chunk's
    # result once more.
    control = (_solve_in_sequence(rig, targets, solver) if warm_start
               else _solve_chunked(rig, targets, solver, chunk))
    return jax.vmap(rig.skin)(control)


@compiled_by()
def _deform_one_device(rig: AbstractRig, targets, solver: AbstractSolver, chunk: int,
                       warm_start: bool):
    return _deform_chunked(rig, targets, solver, chunk, warm_start)


@compiled_by(donate="out")
def _deform_into(rig: Rig, targets, solver: AbstractSolver, chunk: int, *, out):
    # Donated, `out` holds the result (XLA aliases a donated input to an output of its
    # shape), and the skinning writes into it group by group.
    control = rig.frame.to_local(_solve_chunked(rig, targets, solver, chunk))
    return skin_frames_into(rig.skinning, control, rig.frame, out)


def _check_out(out, frames: int, rig: AbstractRig):
    """`out` fit to hold the result, or an error that says why not."""
    if not isinstance(rig, Rig):  # posed into one array: a rig's single mesh
        raise ValueError(f"out holds the frames of one mesh, a Rig's; a "
                         f"{type(rig).__name__}'s parts are posed into new arrays: leave "
                         "out out=.")
    want = (frames, rig.shape_mesh.vertices.shape[0], 2)
    dtype = rig.energy.rest.dtype
    if not isinstance(out, jax.Array) or isinstance(out, jax.core.Tracer):
        raise TypeError(f"out must be a concrete JAX array from an earlier deform_frames call "
                        f"(its memory is reused), got {type(out).__name__}; leave it out under "
                        "jax.jit, or for a new array.")
    if out.is_deleted():
        raise ValueError("out has been deleted (donated to an earlier call): pass the array "
                         "that call returned.")
    if out.shape != want or out.dtype != dtype:
        raise ValueError(f"out must have shape {want} and dtype {dtype} to hold the result, "
                         f"got {out.shape} {out.dtype}; pass a result of the same number of "
                         "frames and rig, or leave it out.")


@compiled_by()
def _deform_sharded(rig: AbstractRig, targets, solver: AbstractSolver, chunk: int, mesh: Mesh):
    # shard_map: each device maps over its own frames (a lax.map over a sharded axis
    # would gather the frames first).
    return jax.shard_map(
        lambda r, t: _deform_chunked(r, t, solver, chunk),
        mesh=mesh,
        in_specs=(PartitionSpec(), PartitionSpec("frames")),
        out_specs=PartitionSpec("frames"),
        # The solver's loops carry values that vary over devices from constants that do
        # not (the rig): no cross-device communication happens, so skip the check.
        check_vma=False,
    )(rig, targets)


def _check_placement(devices, out, warm_start) -> list:
    """The devices to pose on (the default device for None), where `deform_frames` can
    pose this way: frames solved in order, on one device into a new array."""
    if warm_start and (out is not None or (devices and len(devices) > 1)):
        raise ValueError("warm_start=True solves the frames in order on one device, into a "
                         "new array: leave out out= and devices=.")
    return [jax.local_devices()[0]] if devices is None else devices


def _refuse_bad_host_frames(targets, h: int) -> None:
    """Refuse concrete targets that are not real numbers, or whose frames hold NaN or
    infinite values (named by index); traced targets cannot be checked."""
    if isinstance(targets, jax.core.Tracer):
        return
    host = as_array(targets, "targets", f"an array of shape (frames, {h}, 2)")
    if host.dtype.kind not in "iuf":
        raise TypeError(f"targets must be real (x, y) numbers, got {kind_of(host)}.")
    if host.ndim == 3 and host.shape[1:] == (h, 2):
        bad = np.flatnonzero(~np.isfinite(host).all(axis=(1, 2)))
        if len(bad):
            raise ValueError(
                f"targets of {len(bad)} frames contain NaN or infinite values (frames "
                f"{bad[:10].tolist()}{' ...' if len(bad) > 10 else ''}); give finite "
                "targets, or drop those frames."
            )


def _checked_frames(targets, h: int):
    """`targets` as a JAX array of shape `(frames, h, 2)`, or an error that says why
    they cannot be."""
    _refuse_bad_host_frames(targets, h)
    targets = jnp.asarray(targets)
    if targets.ndim != 3 or targets.shape[1:] != (h, 2):
        raise ValueError(
            f"targets must have shape (frames, {h}, 2), one (x, y) per handle and frame, got "
            f"{targets.shape}; for a single frame use rig.deform(targets)."
        )
    if isinstance(targets, jax.core.Tracer):
        return finite_when_traced(targets, NOT_FINITE_TARGETS)
    return targets


def _deform_over_devices(rig: AbstractRig, targets, solver: AbstractSolver, chunk: int, devices):
    """The frames split evenly between `devices` (padded to a multiple of their count),
    the rig replicated, and the result back in frame order without the padding."""
    frames = targets.shape[0]
    per_device = -(-frames // len(devices))
    targets = _pad_frames(targets, len(devices))
    mesh = Mesh(np.asarray(devices), ("frames",))
    targets = jax.device_put(targets, NamedSharding(mesh, PartitionSpec("frames")))
    rig = jax.device_put(rig, NamedSharding(mesh, PartitionSpec()))
    posed = _deform_sharded(rig, targets, solver, min(chunk, per_device), mesh)
    return jax.tree.map(lambda p: p[:frames], posed)


def deform_frames(
    rig: AbstractRig,
    targets: Any,
    solver: Any = DEFAULT_SOLVER,
    *,
    chunk: Any = None,
    devices: Any = None,
    out: Any = None,
    warm_start: bool = False,
) -> Float[Array, "frames n 2"] | tuple[Array, ...]:
    """Deformed shape-mesh vertices for every frame of `targets`.

    One compiled program (cached by shapes and solver, like any `jit`) solves the frames
    `chunk` at a time, each chunk `jax.vmap(rig.solve)`: a plain `FixedG` (the default)
    steps the chunk's frames together, frames last; any other solver is vmapped as JAX
    does. Then `jax.vmap(rig.skin)` skins all frames into the result, a few at a time.
    With several devices the frames are split between them (`jax.shard_map`, the rig
    replicated) and the result comes back in frame order.

    Args:
        rig: the rig, or a `Character` (then the result is a tuple, a part's
            `(frames, n_i, 2)` each, and no `out`).
        targets: `(frames, h, 2)` handle targets, one row of targets per frame.
        solver: the solver of every frame (default: `rig.deform`'s), each from the
            turned start (`Rig.start`).
        chunk: frames solved together on a device. Working memory grows little with
            it (a few numbers per control vertex and frame); the result itself takes
            `frames * n * 2` numbers. Default: the solver's `frames_together` (1024 for
            `FixedG`; 1, frame after frame inside the program, for `FoldFree`, whose
            line searches run every frame of a batch as long as the slowest one's).
        out: optional, the result of an earlier call with as many frames, whose memory
            this call reuses: it is donated, and deleted (`out = deform_frames(rig,
            targets, out=out)` in a loop). Large results otherwise pay the kernel's page
            faults on fresh memory at every call, which dominate for large results
            (`benchmarks/frames.py` measures both). One device only.
        devices: the devices to shard the frames over (default: one, the default device;
            `jax.local_devices()` for all of this process's). Frames are padded to a
            multiple of their count.
        warm_start: solve the frames in order, each from the pose before it (the first
            from its turned start), one after another instead of `chunk` at a time: for
            an animation's frames with `FoldFree`, whose every start is then a pose
            without folds near the answer. On one device, without `out`.

    Returns:
        `(frames, n, 2)` deformed shape-mesh vertices.

    Targets given as arrays are checked first: frames with NaN or infinite targets are
    refused by index. Under `jax.jit` the values are not known yet: they are checked when
    the program runs, which then raises the same error without the index.
    """
    h = rig.handles.count
    dtype = rig.handles.rest.dtype
    check_solver(solver)
    targets = _checked_frames(targets, h)
    chunk = whole_number(solver.frames_together if chunk is None else chunk, "chunk",
                         what=" of frames")
    if targets.shape[0] == 0:
        raise ValueError("targets hold no frames (shape (0, h, 2)); give at least one frame.")
    devices = _check_placement(as_devices(devices), out, warm_start)
    targets = targets.astype(dtype)
    frames = targets.shape[0]
    twin = padded_twin(rig)
    if (out is None and len(devices) == 1 and twin is not None
            and not isinstance(targets, jax.core.Tracer)):
        # A laddered rig poses as its twin, whose program rigs on its rungs share; its
        # own rows are cut on the host (an eager slice compiles a program per size).
        posed = deform_frames(twin, targets, solver, chunk=chunk, devices=devices,
                              warm_start=warm_start)
        return to_device(np.asarray(posed)[:, :rig.shape_mesh.vertices.shape[0]], posed.dtype)
    if out is not None:
        if len(devices) != 1:
            raise ValueError("out works on one device; leave it out to shard frames over "
                             f"{len(devices)} devices.")
        _check_out(out, frames, rig)
        return _deform_into(rig, targets, solver, min(chunk, frames), out=out)
    if len(devices) == 1:
        return _deform_one_device(rig, targets, solver, min(chunk, frames), bool(warm_start))
    return _deform_over_devices(rig, targets, solver, chunk, devices)
