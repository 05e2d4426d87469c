import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets
from mvcjax.geometry import _skinning

from conftest import needs_float64

RIGID = mvcjax.advanced.RigidStart()

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.

METHODS = {"blended": mvcjax.advanced.BlendedMVCSkinning, "mvc": mvcjax.advanced.MVCSkinning,
           "barycentric": mvcjax.advanced.BarycentricSkinning}


@pytest.mark.float64
def test_skinning_weights_are_sound(horse_rig):
    sk = horse_rig.skinning
    assert bool(jnp.all(jnp.isfinite(sk.weights)))
    np.testing.assert_allclose(sk.weights.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(horse_rig.skin(horse_rig.control_mesh.vertices),
                               horse_rig.shape_mesh.vertices, atol=1e-9)  # linear precision
    # A shape vertex that is a control vertex (every V_CG is) has a one-hot row.
    handle_rows = sk.weights[horse_rig.shape_mesh.handles]
    assert float(jnp.max(handle_rows, axis=1).min()) == 1.0


@pytest.mark.float64
def test_dense_skinning_matrix_is_the_same_map(horse_rig):
    pose = horse_rig.control_mesh.vertices + jax.random.normal(
        jax.random.key(2), horse_rig.control_mesh.vertices.shape)
    dense = horse_rig.skinning.matrix(pose.shape[0])
    np.testing.assert_allclose(dense @ pose, horse_rig.skin(pose), atol=1e-9)


@pytest.fixture(scope="module")
def skinned_rigs(horse):
    """The horse rigged with each skinning, in float64 (whichever test builds it first)."""
    needs_float64("skinned_rigs")
    return {s: mvcjax.Rig.build(horse, datasets.horse_handles(), skinning=METHODS[s](),
                                dtype=jnp.float64)
            for s in list(METHODS)}


@pytest.mark.float64
@pytest.mark.parametrize("skinning", list(METHODS))
def test_every_skinning_is_exact_at_rest_and_interpolates(skinned_rigs, skinning):
    rig = skinned_rigs[skinning]
    w = rig.skinning.weights
    assert bool(jnp.all(jnp.isfinite(w)))
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rig.skin(rig.control_mesh.vertices), rig.shape_mesh.vertices,
                               atol=1e-9)
    # A shape vertex on a control vertex follows it exactly, in any pose.
    pose = rig.control_mesh.vertices + jax.random.normal(jax.random.key(5),
                                                         rig.control_mesh.vertices.shape)
    np.testing.assert_allclose(rig.skin(pose)[rig.shape_mesh.handles],
                               pose[rig.control_mesh.handles], atol=1e-9)


@pytest.mark.float64
def test_blended_skinning_is_smoothest_and_the_default(horse, skinned_rigs):
    measured = {}
    paper = mvcjax.FixedG()
    for name, rig in skinned_rigs.items():
        out = rig.deform(rig.handle_positions + datasets.horse_drag(), paper, init=RIGID)
        measured[name] = mvcjax.advanced.smoothness(rig.shape_mesh.vertices, out,
                                                    rig.shape_mesh.faces)
    # The paper's per-triangle MVC jumps across control edges; the blend does not.
    assert measured["blended"] < measured["barycentric"] < measured["mvc"], measured
    # As smooth as the full solve on the shape mesh, at the paper's 15 iterations each.
    full = mvcjax.Rig.build(horse, datasets.horse_handles(), control=mvcjax.FullSolve())
    out = full.deform(full.handle_positions + datasets.horse_drag(), paper, init=RIGID)
    assert measured["blended"] < 1.1 * mvcjax.advanced.smoothness(full.shape_mesh.vertices, out,
                                                          full.shape_mesh.faces), measured
    default = mvcjax.Rig.build(horse, datasets.horse_handles())
    np.testing.assert_array_equal(default.skinning.indices,
                                  skinned_rigs["blended"].skinning.indices)


def test_unknown_skinning_is_explained(horse):
    with pytest.raises(TypeError, match="skinning must be a skinning object"):
        mvcjax.Rig.build(horse, datasets.horse_handles(), skinning="linear")
    with pytest.raises(TypeError, match="skinning must be a skinning object"):
        mvcjax.Rig.build(horse, datasets.horse_handles(), skinning="linear",
                         control=mvcjax.FullSolve())


@pytest.mark.float64
@pytest.mark.parametrize("name", METHODS)
def test_objects_and_names_are_the_same_method(skinned_rigs, horse, name):
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), skinning=METHODS[name](),
                           dtype=jnp.float64)
    assert rig.skinning.method == METHODS[name]()
    np.testing.assert_array_equal(rig.skinning.indices, skinned_rigs[name].skinning.indices)
    np.testing.assert_array_equal(rig.skinning.weights, skinned_rigs[name].skinning.weights)


@pytest.mark.float64
@pytest.mark.parametrize("name", METHODS)
def test_weights_at_the_shape_vertices_are_the_rigs(skinned_rigs, name):
    rig = skinned_rigs[name]
    again = rig.weights_at(np.asarray(rig.shape_mesh.vertices))
    c = rig.control_mesh.vertices.shape[0]
    differ = np.abs(again.matrix(c) - rig.skinning.matrix(c)).max(axis=1) > 1e-9
    if name == "mvc":
        # The paper's map jumps across control edges: a vertex on an edge (to rounding)
        # may be given either side's weights, both exact at rest.
        assert differ.mean() < 0.02, differ.sum()
        np.testing.assert_allclose(again(rig.control_mesh.vertices), rig.shape_mesh.vertices,
                                   atol=1e-9)
    else:
        assert not differ.any(), differ.sum()


@pytest.mark.float64
@pytest.mark.parametrize("name", METHODS)
def test_weights_at_any_points_have_linear_precision(skinned_rigs, name):
    # Mean value and barycentric coordinates reproduce affine maps exactly: points
    # anywhere in the control mesh follow an affine motion of the control vertices.
    rig = skinned_rigs[name]
    cm = np.asarray(rig.control_mesh.vertices)
    rng = np.random.default_rng(0)
    inside = rng.uniform(cm.min(0), cm.max(0), (4000, 2))
    a, b, c = (cm[np.asarray(rig.control_mesh.faces)[:, k]] for k in range(3))
    covered = [_in_triangles(p, a, b, c) for p in inside[:500]]
    points = inside[:500][np.asarray(covered)]
    assert len(points) > 100
    skin = rig.weights_at(points)
    affine = np.array([[1.3, 0.4], [-0.2, 0.7]])
    moved = skin(jnp.asarray(cm @ affine.T + [5.0, -3.0]))
    np.testing.assert_allclose(moved, points @ affine.T + [5.0, -3.0], atol=1e-8)
    assert bool(jnp.all(jnp.isfinite(skin.weights)))


def _in_triangles(p, a, b, c):
    def cross(u, v):
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    return bool(np.any((cross(b - a, p - a) >= 0) & (cross(c - b, p - b) >= 0)
                       & (cross(a - c, p - c) >= 0)))


@pytest.mark.float64
def test_weights_at_points_outside_say_so(horse_rig):
    far = np.asarray(horse_rig.control_mesh.vertices).max(axis=0) + 10.0
    with pytest.raises(ValueError, match="1 of the 2 points lie outside the control mesh"):
        horse_rig.weights_at([np.asarray(horse_rig.handle_positions[0]), far])
    with pytest.raises(ValueError, match="points contains NaN"):
        horse_rig.weights_at([[1.0, np.nan]])


@pytest.mark.float64
def test_weights_at_on_a_full_rig_are_barycentric_on_the_shape_mesh(horse):
    full = mvcjax.Rig.build(horse, datasets.horse_handles(), control=mvcjax.FullSolve())
    assert full.skinning.method == mvcjax.advanced.BarycentricSkinning()
    sm = full.shape_mesh
    centroids = np.asarray(sm.vertices)[np.asarray(sm.faces)].mean(axis=1)
    skin = full.weights_at(centroids)
    np.testing.assert_allclose(skin(sm.vertices), centroids, atol=1e-9)
    np.testing.assert_allclose(np.sort(np.asarray(skin.weights), axis=1)[:, -3:], 1 / 3, atol=1e-6)


@pytest.mark.float64
def test_weights_at_carry_points_inside_jit(horse_rig):
    skin = horse_rig.weights_at(np.asarray(horse_rig.handle_positions))
    targets = horse_rig.handle_positions + datasets.horse_drag()

    @jax.jit
    def follow(skin, targets):
        return skin(horse_rig.solve(targets))

    # The handles are shape vertices: carried alone, they go where the shape takes them.
    expected = horse_rig.deform(targets)[horse_rig.shape_mesh.handles]
    np.testing.assert_allclose(follow(skin, targets), expected, atol=1e-9)


@pytest.mark.float64
@pytest.mark.parametrize("tile", [1, 3, 8])
def test_packed_rows_give_back_the_rows_and_the_same_map(tile):
    # Rows sharing an index list share tiles; the packed map is the rows' map.
    rng = np.random.default_rng(tile)
    lists = np.sort(rng.choice(30, size=(7, 5), replace=True), axis=1)
    index = lists[rng.integers(0, 7, size=100)]
    weight = rng.uniform(-1, 1, size=index.shape)
    tile_index, tile_weight, slot = _skinning.pack_rows(index, weight, tile)
    assert tile_weight.shape[2] == tile and len(np.unique(slot)) == 100
    np.testing.assert_array_equal(tile_index[:, slot // tile].T, index)
    np.testing.assert_array_equal(tile_weight[:, slot // tile, slot % tile].T, weight)
    skin = mvcjax.advanced.Skinning.from_rows(index, weight, mvcjax.advanced.MVCSkinning(),
                                              jnp.float64)
    np.testing.assert_array_equal(skin.indices, index)
    np.testing.assert_array_equal(skin.weights, weight)
    control = jnp.asarray(rng.normal(size=(30, 2)))
    np.testing.assert_allclose(skin(control), np.einsum("nk,nkd->nd", weight, control[index]),
                               atol=1e-12)


@pytest.mark.float64
def test_skinning_rows_are_packed_with_little_padding(skinned_rigs):
    for rig in skinned_rigs.values():
        sk = rig.skinning
        rows = sk.tile_weights.shape[1] * sk.tile_weights.shape[2]
        assert sk.slots.shape[0] <= rows < 1.6 * sk.slots.shape[0]
        assert sk.tile_weights.shape[1] < sk.slots.shape[0] / 4  # few gathers per frame
