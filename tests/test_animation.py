"""Many frames at once: vmapped in chunks, and sharded over devices."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax

from conftest import host_callbacks

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.
# Two float32 computations of the horse's vertices (coordinates up to 480, rounded by up
# to 3e-5) agree to a few roundings.
ROUNDING = 1e-3


def some_frames(rig, count, seed=0):
    rng = np.random.default_rng(seed)
    offsets = rng.normal(scale=8.0, size=(count, *rig.handle_positions.shape))
    return rig.handle_positions[None] + jnp.asarray(offsets, rig.handle_positions.dtype)


def test_frames_match_single_frames(horse_rig32):
    targets = some_frames(horse_rig32, 10)
    together = mvcjax.deform_frames(horse_rig32, targets, chunk=4)  # chunks that do not divide
    assert together.shape == (10, *horse_rig32.shape_mesh.vertices.shape)
    for k in range(10):
        np.testing.assert_allclose(together[k], horse_rig32.deform(targets[k]), atol=ROUNDING)


@pytest.mark.parametrize("solver", [mvcjax.FixedG(iterations=30),
                                    mvcjax.FixedG(iterations=30, anderson=3, unroll=0)],
                         ids=["frames_last", "vmapped"])
@pytest.mark.float64  # Anderson's small least squares amplify float32's rounding
def test_each_batch_path_matches_single_frames(horse_rig, solver):
    # A plain FixedG steps all frames together; any other solver is vmapped.
    targets = some_frames(horse_rig, 5, seed=1)
    together = mvcjax.deform_frames(horse_rig, targets, solver, chunk=2)
    for k in range(5):
        np.testing.assert_allclose(together[k], horse_rig.deform(targets[k], solver), atol=1e-9)


@pytest.mark.float64
def test_gradient_through_frames_matches_single_frames(horse_rig):
    targets = some_frames(horse_rig, 3, seed=2)

    def together(t):
        return jnp.sum(mvcjax.deform_frames(horse_rig, t, chunk=2)[:, ::40] ** 2)

    def one_by_one(t):
        return sum(jnp.sum(horse_rig.deform(t[k])[::40] ** 2) for k in range(3))

    np.testing.assert_allclose(jax.grad(together)(targets), jax.grad(one_by_one)(targets),
                               rtol=1e-9, atol=1e-9)


def test_bad_frames_are_explained(horse_rig32):
    with pytest.raises(ValueError, match="targets must have shape \\(frames, 5, 2\\)"):
        mvcjax.deform_frames(horse_rig32, horse_rig32.handle_positions)
    with pytest.raises(ValueError, match="no frames"):
        mvcjax.deform_frames(horse_rig32, jnp.zeros((0, 5, 2)))
    with pytest.raises(ValueError, match="chunk must be"):
        mvcjax.deform_frames(horse_rig32, some_frames(horse_rig32, 2), chunk=0)
    with pytest.raises(TypeError, match="chunk must be a whole number"):
        mvcjax.deform_frames(horse_rig32, some_frames(horse_rig32, 2), chunk=2.5)
    with pytest.raises(ValueError, match="devices must be a non-empty list"):
        mvcjax.deform_frames(horse_rig32, some_frames(horse_rig32, 2), devices=[])
    with pytest.raises(TypeError, match="real"):
        mvcjax.deform_frames(horse_rig32, some_frames(horse_rig32, 2) * 1j)


def test_frames_with_nan_targets_are_named(horse_rig32):
    frames = np.asarray(some_frames(horse_rig32, 6)).copy()
    frames[2, 1, 0] = np.nan
    frames[4, 0, 1] = np.inf
    with pytest.raises(ValueError, match=r"2 frames .*\[2, 4\]"):
        mvcjax.deform_frames(horse_rig32, frames)
    # Under jit the values are unknown when traced: checked when run, with the words of
    # the plain call's check, instead of giving those frames back non-finite.
    with pytest.raises(Exception, match="targets contain NaN or infinite values"):
        jax.block_until_ready(jax.jit(lambda t: mvcjax.deform_frames(horse_rig32, t))(frames))


@pytest.mark.parametrize("warm_start", [False, True])
def test_frames_are_checked_once_where_they_enter(horse_rig32, warm_start):
    # Traced frames are checked for NaN once, where they enter; the program that solves
    # them holds no check of its own (each would be a host callback there, and JAX's
    # persistent compilation cache keeps no program with one: every process would
    # compile deform_frames again).
    frames = some_frames(horse_rig32, 3)
    jaxpr = jax.make_jaxpr(lambda t: mvcjax.deform_frames(horse_rig32, t,
                                                          warm_start=warm_start))(frames)
    entry, inside = host_callbacks(jaxpr.jaxpr, "_deform_one_device")
    assert entry > 0 and inside == 0, (entry, inside)


def test_frames_into_a_donated_result_reuse_its_memory(horse_rig32, caplog):
    first, second = some_frames(horse_rig32, 6, seed=3), some_frames(horse_rig32, 6, seed=4)
    out = mvcjax.deform_frames(horse_rig32, first, chunk=4)
    where = out.unsafe_buffer_pointer()
    again = mvcjax.deform_frames(horse_rig32, second, chunk=4, out=out)
    assert out.is_deleted()
    assert again.unsafe_buffer_pointer() == where  # the result lives in out's memory
    np.testing.assert_array_equal(again, mvcjax.deform_frames(horse_rig32, second, chunk=4))
    # New numbers, same program.
    with jax.log_compiles(True), caplog.at_level("WARNING", logger="jax"):
        caplog.clear()
        mvcjax.deform_frames(horse_rig32, first, chunk=4, out=again)
    assert not [m for m in caplog.messages if m.startswith("Compiling")], caplog.messages


def test_bad_out_is_explained(horse_rig32):
    frames = some_frames(horse_rig32, 3)
    out = mvcjax.deform_frames(horse_rig32, frames)
    with pytest.raises(ValueError, match="must have shape \\(2, "):
        mvcjax.deform_frames(horse_rig32, frames[:2], out=out)
    with pytest.raises(TypeError, match="concrete JAX array.*got ndarray"):
        mvcjax.deform_frames(horse_rig32, frames, out=np.asarray(out))
    with pytest.raises(ValueError, match="one device"):
        mvcjax.deform_frames(horse_rig32, frames, out=out, devices=jax.devices() * 2)
    mvcjax.deform_frames(horse_rig32, frames, out=out)
    with pytest.raises(ValueError, match="deleted"):
        mvcjax.deform_frames(horse_rig32, frames, out=out)


SHARDED = """
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp, numpy as np, mvcjax
from mvcjax import datasets
assert len(jax.devices()) == 4, jax.devices()
rig = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles())
rng = np.random.default_rng(0)
targets = rig.handle_positions[None] + rng.normal(scale=8.0, size=(10, 5, 2))
one = mvcjax.deform_frames(rig, targets, chunk=3)
four = mvcjax.deform_frames(rig, targets, chunk=3, devices=jax.devices())
assert four.shape == (10, *rig.shape_mesh.vertices.shape), four.shape
character = mvcjax.Character.build(datasets.layered_figure(),
                                   datasets.layered_figure_handles())
wave = datasets.layered_figure_wave(6)
parts = mvcjax.deform_frames(character, wave, chunk=2, devices=jax.devices())
alone = mvcjax.deform_frames(character, wave, chunk=2)
print(max(float(jnp.abs(one - four).max()),
          *(float(jnp.abs(a - b).max()) for a, b in zip(parts, alone))))
"""


def test_frames_sharded_over_four_devices_give_the_same_result():
    # A rig's, and a character's (the same protocol).
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4"
    env = {**os.environ, "XLA_FLAGS": flags,
           "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", SHARDED], env=env, capture_output=True,
                         text=True, check=True)
    assert float(out.stdout) < 1e-9


@pytest.mark.parametrize("factor", [mvcjax.advanced.DenseG(), mvcjax.advanced.SparseLU()],
                         ids=["dense", "sparse"])
@pytest.mark.float64
def test_fixed_g_vmapped_steps_all_frames_as_plain_batching_would(horse, factor):
    # Under jax.vmap a plain FixedG steps every frame together (frames on the last axis),
    # through its batching rule; JAX's own batching of the loop iterates the same map.
    rig = mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(), factor=factor)
    targets = some_frames(rig, 8, seed=3)  # enough frames for the rule
    local = jax.vmap(rig._pinned)(targets)
    starts = jax.vmap(lambda t: rig.frame.to_local(rig.start(t)))(targets)
    solver = mvcjax.FixedG(iterations=20)
    fast, fast_info = jax.vmap(solver.solve, (None, None, 0, 0))(rig.energy, rig.factor,
                                                                  local, starts)
    plain, plain_info = jax.vmap(solver._iterate, (None, None, 0, 0))(rig.energy, rig.factor,
                                                                       local, starts)
    np.testing.assert_allclose(fast, plain, atol=1e-9)
    np.testing.assert_allclose(fast_info.energy, plain_info.energy, rtol=1e-9)
    np.testing.assert_array_equal(fast_info.converged, plain_info.converged)
    np.testing.assert_array_equal(fast_info.iterations, plain_info.iterations)


@pytest.mark.parametrize("solver", [mvcjax.FixedG(iterations=30), mvcjax.FoldFree()],
                         ids=["FixedG", "FoldFree"])
@pytest.mark.float64
def test_warm_started_frames_start_each_from_the_pose_before(horse_rig, solver):
    frames = some_frames(horse_rig, 4, seed=5)
    posed = mvcjax.deform_frames(horse_rig, frames, solver, warm_start=True)
    control = horse_rig.start(frames[0])
    for frame, targets in zip(posed, frames):
        control = horse_rig.solve(targets, solver, init=control)
        # FoldFree stops at its tolerance, compiled apart: to 1e-6 of the rig's size.
        np.testing.assert_allclose(frame, horse_rig.skin(control), rtol=0,
                                   atol=1e-6 * float(horse_rig.frame.scale))
    with pytest.raises(ValueError, match="warm_start=True"):
        mvcjax.deform_frames(horse_rig, frames, solver, warm_start=True,
                             out=jnp.zeros_like(posed))
