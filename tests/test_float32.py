"""What users run, as they run it: JAX's default 32-bit floats, through the default
paths, against float64 references."""

import jax
import jax.numpy as jnp
import numpy as np

import mvcjax
from mvcjax import datasets

from conftest import float64_on


def test_the_default_paths_give_float32_near_float64(horse_rig32):
    rig32 = horse_rig32
    with float64_on():
        rig64 = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles(), dtype=jnp.float64)
        targets = np.asarray(rig64.handle_positions) + datasets.horse_drag()
        reference = np.asarray(rig64.deform(targets))
    diagonal = float(np.linalg.norm(np.ptp(reference, axis=0)))
    assert rig32.shape_mesh.vertices.dtype == jnp.float32
    t = jnp.asarray(targets, jnp.float32)
    single = jax.jit(rig32.deform)(t)
    frames = mvcjax.deform_frames(rig32, jnp.stack([t, t]))
    unfolded, info = rig32.deform(t, mvcjax.FoldFree(), return_info=True)
    grad = jax.grad(lambda x: jnp.sum(rig32.deform(x)[:, 1]))(t)
    picture = mvcjax.Renderer.build(rig32, size=(64, 64))(single)
    for result in (single, frames[0], frames[1]):
        assert result.dtype == jnp.float32
        np.testing.assert_allclose(np.asarray(result), reference, atol=1e-4 * diagonal)
    assert unfolded.dtype == jnp.float32 and int(info.inverted) == 0
    assert grad.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(grad)))
    assert picture.dtype == jnp.float32 and float(picture[..., 3].max()) > 0.5
