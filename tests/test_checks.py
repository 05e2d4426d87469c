"""Bad input at the public API's edges: each refused by an error that names the input,
the problem and the fix, never a NaN or a JAX-internal message."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import mvcjax

from conftest import drag


@pytest.fixture(scope="module")
def rig32(horse):
    return mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(), dtype=jnp.float32)


@pytest.mark.parametrize("solver", ["GaussNewton", mvcjax.GaussNewton, 3,
                                    optx.GaussNewton(rtol=1e-6, atol=1e-6)],
                         ids=["string", "class", "number", "optimistix"])
def test_a_solver_must_be_an_object(horse_rig32, solver):
    t = drag(horse_rig32, np.zeros((5, 2)))
    renderer = mvcjax.Renderer.build(horse_rig32, size=(16, 16))
    picture = np.zeros((16, 16, 4), np.float32)
    if isinstance(solver, str):
        expected = ("the string 'GaussNewton' (options are objects); write "
                    "solver=mvcjax.GaussNewton()")
    elif isinstance(solver, type):
        expected = "the class GaussNewton; write solver=mvcjax.GaussNewton()"
    elif isinstance(solver, optx.GaussNewton):  # another library's solver, named as such
        expected = "got optimistix's GaussNewton."
    else:
        expected = "such as mvcjax.FixedG()"
    for call in (lambda: horse_rig32.deform(t, solver),
                 lambda: mvcjax.deform_frames(horse_rig32, jnp.stack([t, t]), solver=solver),
                 lambda: mvcjax.fit_targets(horse_rig32, renderer, picture, solver=solver)):
        with pytest.raises(TypeError, match=re.escape(expected)):
            call()


def test_ragged_sequences_are_named(horse_rig32):
    with pytest.raises(ValueError, match=r"targets must be .*ragged"):
        horse_rig32.deform([[1.0, 2.0], [3.0]])
    with pytest.raises(ValueError, match=r"targets must be .*ragged"):
        mvcjax.deform_frames(horse_rig32, [[[1.0, 2.0]], [[3.0]]])
    with pytest.raises(ValueError, match=r"image must be .*ragged"):
        mvcjax.Shape.from_image([[True, False], [True]])
    with pytest.raises(ValueError, match=r"init must be .*ragged"):
        horse_rig32.deform(horse_rig32.handle_positions, init=[[1.0, 2.0], [3.0]])


def test_a_weight_must_be_a_number():
    with pytest.raises(TypeError, match=r"Weights\(mvc='stiff'\): a weight is a number"):
        mvcjax.Weights(mvc="stiff")


def test_non_finite_init_is_refused(horse_rig32):
    bad = np.full(horse_rig32.control_mesh.vertices.shape, np.nan)
    with pytest.raises(ValueError, match="init holds NaN"):
        horse_rig32.deform(horse_rig32.handle_positions, init=bad)
    # Traced, the check runs with the program.
    with pytest.raises(Exception, match="init holds NaN"):
        jax.jit(lambda i: horse_rig32.deform(horse_rig32.handle_positions, init=i))(bad)


@pytest.mark.parametrize("weight", [np.nan, -1.0, np.inf])
def test_bad_weights_under_jit_raise_instead_of_nan(horse_rig32, weight):
    t = drag(horse_rig32, [[10.0, 0.0]] + [[0.0, 0.0]] * 4)
    deform = jax.jit(lambda w: horse_rig32.with_weights(mvcjax.Weights(mvc=w)).deform(t))
    assert np.all(np.isfinite(np.asarray(deform(2.0))))
    with pytest.raises(Exception, match="Weights given under jit or grad must be finite"):
        deform(weight)


def test_targets_beyond_the_rigs_precision_are_refused(rig32):
    t = np.asarray(rig32.handle_positions, np.float64) * 1e39
    with pytest.raises(ValueError, match="beyond float32's range.*dtype=jnp.float64"):
        rig32.deform(t)
