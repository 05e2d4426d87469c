"""Rigs built with a `SizeLadder`: padded twins that share compiled programs between
rigs of similar sizes, invisible in what the rig holds and returns."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, strategies as st

import mvcjax
from mvcjax.energy import dense_factor
from mvcjax.rig import padded_twin


def star(points, outer, inner, centre=(0.0, 0.0)):
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False)
    r = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1) + np.asarray(centre)


def build(polygon, handles="points", **options):
    shape = mvcjax.Shape.from_polygon(polygon)
    centre = polygon.mean(axis=0)
    if handles == "points":
        pins = [tuple(centre + 0.3 * (p - centre)) for p in polygon[::2][:3]]
    else:  # a bone (its pinned points follow its length) and a point
        pins = [mvcjax.Bone(tuple(centre + 0.4 * (polygon[0] - centre)),
                            tuple(centre + 0.4 * (polygon[4] - centre))),
                tuple(centre + 0.3 * (polygon[2] - centre))]
    return mvcjax.Rig.build(shape, pins, shape_spacing=shape.diagonal / 30, **options)


def moved(rig, seed=0):
    rng = np.random.default_rng(seed)
    rest = np.asarray(rig.handle_positions, np.float64)
    return rest + rng.normal(scale=0.1, size=rest.shape) * float(rig.frame.scale)


@given(st.integers(1, 10**6), st.sampled_from([2 ** 0.25, 2 ** 0.5, 2.0, 3.0]))
def test_a_rung_is_the_smallest_rung_at_least_the_size(n, step):
    ladder = mvcjax.SizeLadder(step)
    rung = ladder.rung(n)
    assert n <= rung <= max(np.ceil(n * step), n + 1)
    assert ladder.rung(rung) == rung  # a rung is its own rung
    assert ladder.rung(n - 1) <= rung  # never smaller for a larger size


@pytest.mark.float64
@pytest.mark.parametrize("handles", ["points", "bone"])
def test_the_factor_cut_from_the_twins_is_the_rigs_own(handles):
    rig = build(star(7, 30.0, 18.0, (100.0, -40.0)), handles, dtype=jnp.float64,
                ladder=mvcjax.SizeLadder())
    assert padded_twin(rig) is not None
    own = dense_factor(rig.energy)
    for name in ("shape", "handle", "normal", "normal_inverse", "rows", "coef", "length",
                 "rest", "rotation"):
        a, b = np.asarray(getattr(rig.factor, name)), np.asarray(getattr(own, name))
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.abs(b).max(), err_msg=name)
    assert rig.factor.blocks == own.blocks
    # The spread tables gather the same A^T W b (an entry whose coefficient rounds to
    # zero in one program and not in the other may be listed in one table only).
    b = np.random.default_rng(0).normal(size=own.rows.shape[0] + 1)
    b[-1] = 0.0

    def gathered(factor):
        k = factor.rows.shape[1]
        return np.sum(np.asarray(factor.spread_coef)
                      * b[np.minimum(np.asarray(factor.spread) // k, len(b) - 1)], axis=1)

    np.testing.assert_allclose(gathered(rig.factor), gathered(own), rtol=0, atol=1e-9)


def plain_and_laddered(handles):
    polygon = star(9, 3.0, 2.2, (-5.0, 7.0))
    return (build(polygon, handles, dtype=jnp.float64),
            build(polygon, handles, dtype=jnp.float64, ladder=mvcjax.SizeLadder()))


@pytest.mark.float64
@pytest.mark.parametrize("solver", [mvcjax.FixedG(), mvcjax.GaussNewton(),
                                    mvcjax.FoldFree()], ids=lambda s: type(s).__name__)
@pytest.mark.parametrize("handles", ["points", "bone"])
def test_a_laddered_rig_holds_and_returns_what_a_plain_rig_does(solver, handles):
    plain, rig = plain_and_laddered(handles)
    twin = padded_twin(rig)
    assert twin.shape_mesh.vertices.shape[0] > rig.shape_mesh.vertices.shape[0]
    # What the rig holds: its own arrays, the twin's sizes nowhere, and the structure of
    # a plain rig (stacks and tree maps mix them).
    assert jax.tree.structure(rig) == jax.tree.structure(plain)
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(rig),
                            jax.tree.leaves(plain)):
        assert np.shape(a) == np.shape(b), jax.tree_util.keystr(path)
    np.testing.assert_array_equal(rig.shape_mesh.vertices, plain.shape_mesh.vertices)
    targets, scale = moved(plain), float(plain.frame.scale)
    got, info = rig.deform(targets, solver, return_info=True)
    want, want_info = plain.deform(targets, solver, return_info=True)
    assert got.shape == want.shape and got.dtype == want.dtype
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8 * scale)
    assert bool(info.converged) == bool(want_info.converged)
    assert int(info.inverted) == int(want_info.inverted)
    np.testing.assert_allclose(info.energy, want_info.energy, rtol=1e-7,
                               atol=1e-12 * scale**2)


@pytest.mark.float64
def test_a_laddered_rig_solves_from_every_start_as_a_plain_rig_does():
    plain, rig = plain_and_laddered("points")
    targets, scale = moved(plain), float(plain.frame.scale)
    previous = plain.solve(targets, mvcjax.FixedG(iterations=3))
    for init in (mvcjax.advanced.RestStart(), previous):
        np.testing.assert_allclose(rig.deform(targets, init=init),
                                   plain.deform(targets, init=init), rtol=0,
                                   atol=1e-8 * scale)
        control = rig.solve(targets, init=init)
        assert control.shape == plain.control_mesh.vertices.shape
        np.testing.assert_allclose(control, plain.solve(targets, init=init), rtol=0,
                                   atol=1e-8 * scale)
    with pytest.raises(ValueError, match="init must have the control mesh's shape"):
        rig.deform(targets, init=np.zeros((3, 2)))
    # Traced, the rig is itself: the same answer through the caller's jit, whether it
    # takes the rig as an argument or closes over it and traces the targets alone.
    np.testing.assert_allclose(jax.jit(mvcjax.Rig.deform)(rig, targets), rig.deform(targets),
                               rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(jax.jit(lambda t: rig.deform(t))(targets), rig.deform(targets),
                               rtol=0, atol=1e-8 * scale)
    # New weights: the twin follows, and the rig still poses as a plain one.
    weights = mvcjax.Weights(mvc=0.5, handle=40.0, arap=3.0)
    reweighted = rig.with_weights(weights)
    assert padded_twin(reweighted) is not None
    np.testing.assert_allclose(reweighted.deform(targets),
                               plain.with_weights(weights).deform(targets), rtol=0,
                               atol=1e-8 * scale)
    stack = mvcjax.Rig.stack([plain, rig.with_weights(mvcjax.Weights())])
    both = jax.vmap(lambda r, t: r.deform(t))(stack, np.stack([targets, targets]))
    np.testing.assert_allclose(both[1], rig.deform(targets), rtol=0, atol=1e-8 * scale)
    frames = np.stack([targets, moved(plain, seed=1)])
    posed = mvcjax.deform_frames(rig, frames)
    assert posed.shape == (2, *plain.shape_mesh.vertices.shape)
    np.testing.assert_allclose(posed, mvcjax.deform_frames(plain, frames), rtol=0,
                               atol=1e-8 * scale)


def sizes(tree):
    leaves, structure = jax.tree.flatten(tree)
    return structure, [(np.shape(a), getattr(a, "dtype", type(a))) for a in leaves]


def test_rigs_of_similar_sizes_share_the_twins_programs(caplog):
    ladder = mvcjax.SizeLadder()
    first = build(star(7, 30.0, 14.0), ladder=ladder)
    first.deform(moved(first))
    # A star a little larger: other sizes of its own, the same rungs.
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        caplog.clear()
        second = build(star(7, 31.0, 14.0, (3.0, 1.0)), ladder=ladder)
        posed = second.deform(moved(second))
        compiled = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
    assert second.shape_mesh.vertices.shape != first.shape_mesh.vertices.shape
    assert sizes(padded_twin(second)) == sizes(padded_twin(first))
    assert compiled == []
    assert posed.shape == second.shape_mesh.vertices.shape
    assert np.all(np.isfinite(posed))
    # Without the ladder, that rig compiles its own.
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        caplog.clear()
        plain = build(star(7, 31.0, 14.0, (3.0, 1.0)))
        plain.deform(moved(plain))
        assert any("Compiling" in r.getMessage() for r in caplog.records)
    np.testing.assert_allclose(posed, plain.deform(moved(plain)), rtol=0,
                               atol=1e-4 * float(plain.frame.scale))


def test_a_transformed_rig_keeps_no_twin_and_still_poses():
    rig = build(star(5, 10.0, 5.0), ladder=mvcjax.SizeLadder())
    assert padded_twin(jax.tree.map(lambda a: a, rig)) is not None  # the same arrays
    copied = jax.tree.map(lambda a: a.copy(), rig)
    assert padded_twin(copied) is None
    reweighed = eqx.tree_at(lambda r: r.energy.weights.arap, rig, rig.energy.weights.arap * 2)
    assert padded_twin(reweighed) is None
    np.testing.assert_allclose(copied.deform(moved(rig)), rig.deform(moved(rig)), rtol=0,
                               atol=1e-4 * float(rig.frame.scale))


def test_a_sparse_factor_is_built_without_a_twin():
    rig = build(star(5, 10.0, 5.0), ladder=mvcjax.SizeLadder(),
                factor=mvcjax.advanced.SparseLU())
    assert padded_twin(rig) is None
    assert np.all(np.isfinite(rig.deform(moved(rig))))


def test_a_bad_ladder_is_refused_with_the_fix():
    with pytest.raises(TypeError, match=r"ladder must be an mvcjax.SizeLadder\(\)"):
        build(star(5, 10.0, 5.0), ladder=True)
    with pytest.raises(ValueError, match="a number above 1"):
        mvcjax.SizeLadder(step=1.0)
    with pytest.raises(ValueError, match="a number above 1"):
        mvcjax.SizeLadder(step=True)
    assert mvcjax.SizeLadder(step=np.float32(1.5)).rung(10) == 12
    with pytest.raises(ValueError, match="ladder= would only add padded twins"):
        mvcjax.Character.build(mvcjax.datasets.layered_figure(),
                               mvcjax.datasets.layered_figure_handles(),
                               ladder=mvcjax.SizeLadder())
