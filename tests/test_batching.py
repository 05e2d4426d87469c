"""The natural JAX spellings: `jax.jit(rig.deform)`, and `jax.vmap` of `solve`, `skin` and
`deform` through their batching rules, which must give what JAX's own batching gives."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax.core import with_batching_rule
from mvcjax.geometry import _skinning

from conftest import directional_derivatives

# Tests that compare with references to many digits, or the solvers' internals, are
# marked float64; the others run in float32, as users do.
# Two float32 computations of the horse's vertices (coordinates up to 480, rounded by up
# to 3e-5) agree to a few roundings.
ROUNDING = 1e-3


def some_frames(rig, count, seed=0, scale=8.0):
    rng = np.random.default_rng(seed)
    offsets = rng.normal(scale=scale, size=(count, *rig.handle_positions.shape))
    return rig.handle_positions[None] + jnp.asarray(offsets, rig.handle_positions.dtype)


def test_jit_of_the_bound_methods_works_and_compiles_once(horse_rig32):
    frames = some_frames(horse_rig32, 3)
    deform = jax.jit(horse_rig32.deform)
    for t in frames:
        np.testing.assert_allclose(deform(t), horse_rig32.deform(t), atol=ROUNDING)
    assert deform._cache_size() == 1  # new targets: no new program
    # The rig as an argument: one program for every rig of these sizes.
    np.testing.assert_allclose(jax.jit(mvcjax.Rig.deform)(horse_rig32, frames[0]),
                               deform(frames[0]), atol=ROUNDING)
    control = jax.jit(horse_rig32.solve)(frames[0])
    np.testing.assert_allclose(control, horse_rig32.solve(frames[0]), atol=ROUNDING)
    np.testing.assert_allclose(jax.jit(horse_rig32.skin)(control), horse_rig32.skin(control),
                               atol=ROUNDING)
    renderer = mvcjax.Renderer.build(horse_rig32, size=(24, 32))
    np.testing.assert_allclose(jax.jit(renderer)(horse_rig32.shape_mesh.vertices),
                               renderer(horse_rig32.shape_mesh.vertices), atol=1e-6)


def test_equal_rigs_hash_equal(horse):
    def paper(**weights):
        return mvcjax.Rig.build(horse, mvcjax.datasets.horse_handles(),
                                weights=mvcjax.Weights.paper(**weights))

    rig, again = paper(), paper()
    assert again == rig and hash(again) == hash(rig)
    other = rig.with_weights(mvcjax.Weights.paper(length=3.0))
    assert other != rig  # same structure, other values: same bucket, not equal
    assert hash(other) == hash(rig)


@pytest.mark.float64
def test_vmap_of_deform_solve_and_skin_match_single_frames(horse_rig):
    frames = some_frames(horse_rig, 5, seed=1)
    shape = jax.jit(jax.vmap(horse_rig.deform))(frames)
    control, info = jax.vmap(lambda t: horse_rig.solve(t, return_info=True))(frames)
    skinned = jax.vmap(horse_rig.skin)(control)
    for k, t in enumerate(frames):
        one, one_info = horse_rig.solve(t, return_info=True)
        np.testing.assert_allclose(control[k], one, atol=1e-9)
        np.testing.assert_allclose(info.energy[k], one_info.energy, rtol=1e-9)
        assert bool(info.converged[k]) == bool(one_info.converged)
        assert int(info.iterations[k]) == int(one_info.iterations)
        np.testing.assert_allclose(shape[k], horse_rig.deform(t), atol=1e-9)
        np.testing.assert_allclose(skinned[k], horse_rig.skin(one), atol=1e-9)


def _rule_and_plain(rig, case, frames):
    """A kept batching rule (or `deform_frames`' skinning into an array) and the plain
    `jax.vmap` of the single frame's path it replaces, as `benchmarks/vmap_rules.py`
    times them."""
    solver = mvcjax.FixedG()
    local = jax.vmap(rig.frame.to_local)(frames)
    pinned = jax.vmap(rig.handles.pinned_targets)(local)
    starts = jax.vmap(lambda t: rig._local_start(t, mvcjax.advanced.TurnedStart()))(local)
    if case == "fixed_g":
        def solve_with(fn):
            return jax.vmap(lambda p, s: fn(rig.energy, rig.factor, p, s)[0])(pinned, starts)
        return solve_with(solver.solve), solve_with(solver._iterate)
    control = jax.vmap(lambda p, s: solver.solve(rig.energy, rig.factor, p, s)[0])(
        pinned, starts)
    plain = jax.vmap(lambda v: _skinning._skin_in(rig.skinning, v, rig.frame))(control)
    if case == "skinning":
        return jax.vmap(lambda v: rig.skinning(v, rig.frame))(control), plain
    out = jnp.full(plain.shape, jnp.nan, plain.dtype)
    return _skinning.skin_frames_into(rig.skinning, control, rig.frame, out), plain


@pytest.mark.parametrize("case", ["fixed_g", "skinning", "skin_into"])
@pytest.mark.parametrize("rig_name, tolerance", [("horse_rig", 1e-12), ("horse_rig32", 1e-6)],
                         ids=["float64", "float32"])
@pytest.mark.float64
def test_each_kept_rule_agrees_with_the_plain_vmap(request, rig_name, tolerance, case):
    # The second implementations round differently from JAX's batching of the single
    # frame's path, and by no more than that: within a few roundings of the shape's size.
    rig = request.getfixturevalue(rig_name)
    fast, plain = _rule_and_plain(rig, case, some_frames(rig, 37, seed=6))
    assert fast.dtype == plain.dtype == rig.shape_mesh.vertices.dtype
    # Control vertices in the rig's frame (unit diagonal); shape vertices in the user's.
    size = 1.0 if case == "fixed_g" else float(rig.frame.scale)
    np.testing.assert_allclose(fast, plain, rtol=0, atol=tolerance * size)


@pytest.mark.float64
def test_vmap_takes_the_batching_rules(horse_rig, monkeypatch):
    # The fixed-G rule steps the frames together; the skinning's is one batched product
    # over blocks of rows, a few frames at a time.
    calls = {"solve": 0, "skin": 0}
    rule, blocks = mvcjax.FixedG._iterate_frames, _skinning._skin_blocks

    def count(name, fn):
        def counted(*a, **k):
            calls[name] += 1
            return fn(*a, **k)
        return counted

    monkeypatch.setattr(mvcjax.FixedG, "_iterate_frames", count("solve", rule))
    monkeypatch.setattr(_skinning, "_skin_blocks", count("skin", blocks))
    from mvcjax.solvers._fixed_g import FEWEST_FRAMES_STEPPED_TOGETHER as fewest

    # A few frames go through JAX's batching of the single frame's loop, more through
    # the rule.
    jax.make_jaxpr(jax.vmap(horse_rig.solve))(some_frames(horse_rig, fewest - 1))
    assert not calls["solve"]
    frames = some_frames(horse_rig, fewest)
    control = jax.vmap(horse_rig.solve)(frames)
    assert calls["solve"]
    jax.make_jaxpr(jax.vmap(horse_rig.skin))(control)
    assert calls["skin"]
    # Batched over the rig, the rules decline: JAX's own batching.
    calls.update(skin=0)
    jax.make_jaxpr(jax.vmap(lambda s, v: s(v), in_axes=(None, 0)))(horse_rig.skinning, control)
    assert calls["skin"]
    calls.update(skin=0)
    both = jax.tree.map(lambda *x: jnp.stack(x), horse_rig.skinning, horse_rig.skinning)
    jax.make_jaxpr(jax.vmap(lambda s, v: s(v)))(both, control[:2])
    assert not calls["skin"]


@pytest.mark.parametrize("frames, group", [(1, None), (5, None), (37, 8)])
def test_the_blocked_skinning_of_many_frames_matches_single_frames(horse_rig32, frames, group,
                                                                   monkeypatch):
    # One product for a few frames; groups of 8 frames for 37 (the last padded, then cut).
    if group:
        monkeypatch.setattr(_skinning, "frames_per_product", lambda n: group)
    control = jax.vmap(horse_rig32.solve)(some_frames(horse_rig32, frames, seed=3))
    many = jax.vmap(horse_rig32.skin)(control)
    assert many.shape == (frames, *horse_rig32.shape_mesh.vertices.shape)
    single = jax.jit(horse_rig32.skin)
    for k in range(frames):
        np.testing.assert_allclose(many[k], single(control[k]), atol=ROUNDING)


def test_points_in_no_order_skip_the_blocks(horse_rig32):
    # Blocks of scattered points would be as wide as a dense W: none are built, and vmap
    # maps the single frame's skinning instead, with the same result.
    vertices = np.asarray(horse_rig32.shape_mesh.vertices)
    points = vertices[np.random.default_rng(0).permutation(len(vertices))]
    scattered = horse_rig32.weights_at(points)
    assert scattered.block_weights.shape[0] == 0
    assert horse_rig32.weights_at(vertices).block_weights.shape[0] > 0
    control = jax.vmap(horse_rig32.solve)(some_frames(horse_rig32, 3, seed=4))
    many = jax.vmap(scattered)(control)
    single = jax.jit(scattered)
    for k in range(3):
        np.testing.assert_allclose(many[k], single(control[k]), atol=ROUNDING)


@pytest.mark.parametrize("frames, group", [(5, None), (37, 8)])
def test_skinning_into_an_array_matches_single_frames(horse_rig32, frames, group, monkeypatch):
    # Groups of 8 for 37 frames: four in the loop, the last five after it.
    if group:
        monkeypatch.setattr(_skinning, "frames_per_product", lambda n: group)
    control = jax.vmap(horse_rig32.solve)(some_frames(horse_rig32, frames, seed=5))
    local = jax.vmap(horse_rig32.frame.to_local)(control)
    out = jnp.full((frames, *horse_rig32.shape_mesh.vertices.shape), jnp.nan)
    into = jax.jit(_skinning.skin_frames_into)(horse_rig32.skinning, local, horse_rig32.frame, out)
    single = jax.jit(horse_rig32.skin)
    for k in range(frames):
        np.testing.assert_allclose(into[k], single(control[k]), atol=ROUNDING)
    # Scattered points have no blocks: their frames are mapped one by one.
    vertices = np.asarray(horse_rig32.shape_mesh.vertices)
    order = np.random.default_rng(1).permutation(len(vertices))
    scattered = horse_rig32.weights_at(vertices[order])
    assert scattered.block_weights.shape[0] == 0
    into = _skinning.skin_frames_into(scattered, local, horse_rig32.frame, out)
    np.testing.assert_allclose(into[-1], jax.jit(scattered)(local[-1], horse_rig32.frame),
                               atol=ROUNDING)


def test_blocks_hold_the_rows_exactly(horse_rig32):
    # Each block's dense weights are the rows of W, in order: W from the blocks equals
    # W from the packed tiles (both from the same rows).
    s = horse_rig32.skinning
    c = horse_rig32.control_mesh.vertices.shape[0]
    n = s.slots.shape[0]
    b, j, r = s.block_weights.shape
    from_blocks = np.zeros((b * r, c))
    for i in range(b):
        np.add.at(from_blocks[i * r:(i + 1) * r].T, np.asarray(s.block_indices[i]),
                  np.asarray(s.block_weights[i]))
    np.testing.assert_array_equal(from_blocks[:n], np.asarray(s.matrix(c)))
    assert not from_blocks[n:].any()
    assert b == -(-n // r) and j < c  # a block uses a few of the control vertices


@pytest.mark.float64
def test_a_batch_of_rigs_falls_back_to_jax_batching(horse_rig):
    # Rules are written for frames of one rig; rigs batched with their targets (here two
    # term weightings) are batched by JAX, and agree with each rig alone.
    rigs = [horse_rig, horse_rig.with_weights(mvcjax.Weights.paper(length=4.0))]
    both = jax.tree.map(lambda *x: jnp.stack(x), *rigs)
    frames = some_frames(horse_rig, 2, seed=2)
    out = jax.vmap(lambda r, t: r.deform(t))(both, frames)
    for k in range(2):
        np.testing.assert_allclose(out[k], rigs[k].deform(frames[k]), atol=1e-9)


@pytest.mark.float64
def test_gradients_through_vmap_match_finite_differences_in_both_modes(horse_rig):
    frames = some_frames(horse_rig, 2, seed=4)

    def batched(t):
        return jnp.sum(jax.vmap(horse_rig.deform)(t)[:, ::50] ** 2)

    exact, approx = directional_derivatives(batched, frames, h=1e-4)
    assert exact == pytest.approx(approx, rel=1e-6)
    # Forward mode through the rules' JVP agrees with reverse mode: <u, J d> = <J^T u, d>.
    shapes = jax.vmap(horse_rig.deform)
    d = jax.random.normal(jax.random.key(5), frames.shape, frames.dtype)
    out, forward = jax.jit(lambda t, d: jax.jvp(shapes, (t,), (d,)))(frames, d)
    u = jax.random.normal(jax.random.key(6), out.shape, out.dtype)
    (reverse,) = jax.jit(lambda t, u: jax.vjp(shapes, t)[1](u))(frames, u)
    assert float(jnp.sum(u * forward)) == pytest.approx(float(jnp.sum(reverse * d)), rel=1e-9)


def test_with_batching_rule_declining_is_plain_vmap():
    f = with_batching_rule(lambda x, y: jnp.sin(x) * y, lambda size, batched, x, y: None)
    x, y = jnp.linspace(0, 1, 4), jnp.arange(4.0)
    np.testing.assert_allclose(jax.vmap(f)(x, y), jnp.sin(x) * y)
    np.testing.assert_allclose(jax.vmap(f, (0, None))(x, 2.0), 2 * jnp.sin(x))
    np.testing.assert_allclose(jax.grad(lambda x: jnp.sum(jax.vmap(f)(x, y)))(x),
                               jnp.cos(x) * y)


def test_a_rule_runs_under_vmap_only_and_derivatives_follow_the_plain_function():
    # A deliberately different rule shows which path ran.
    f = with_batching_rule(lambda x: x**2, lambda size, batched, x: (x**2 + 1.0, True))
    x = jnp.arange(3.0)
    np.testing.assert_allclose(f(x[1]), 1.0)
    np.testing.assert_allclose(jax.vmap(f)(x), x**2 + 1.0)
    np.testing.assert_allclose(jax.vmap(jax.grad(f))(x), 2 * x)
    np.testing.assert_allclose(jax.jacfwd(f)(2.0), 4.0)
