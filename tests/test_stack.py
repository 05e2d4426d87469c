"""Stacks of rigs and renderers (`Rig.stack`, `Renderer.stack`): padded to common sizes
without changing any result, posed and drawn by `jax.vmap` over characters (and
frames) in one program, with gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax


def star(points: int, outer: float, inner: float, centre=(0.0, 0.0)) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False)
    r = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1) + np.asarray(centre)


# Stars of different sizes, places and point counts: meshes of different sizes.
STARS = [(5, 10.0, 5.0, (0.0, 0.0)), (7, 30.0, 18.0, (100.0, -40.0)),
         (9, 3.0, 2.2, (-5.0, 7.0))]


def star_rigs(dtype, handles="points", **options):
    rigs = []
    for points, outer, inner, centre in STARS:
        polygon = star(points, outer, inner, centre)
        shape = mvcjax.Shape.from_polygon(polygon)
        centre = np.asarray(centre)
        if handles == "points":
            pins = [tuple(centre + 0.3 * (p - centre)) for p in polygon[::2][:3]]
        else:  # a bone across the middle (its pinned points vary with its length), a point
            a, b = centre + 0.4 * (polygon[0] - centre), centre + 0.4 * (polygon[4] - centre)
            pins = [mvcjax.Bone(tuple(a), tuple(b)), tuple(centre + 0.3 * (polygon[2]
                                                                          - centre))]
        rigs.append(mvcjax.Rig.build(shape, pins, shape_spacing=shape.diagonal / 30,
                                     dtype=dtype, **options))
    return rigs


def targets_for(rigs, seed=0, frames=None):
    rng = np.random.default_rng(seed)
    shape = (len(rigs),) + ((frames,) if frames else ()) + rigs[0].handle_positions.shape
    moves = rng.normal(scale=0.08, size=shape)
    rest = np.stack([np.asarray(r.handle_positions, np.float64) for r in rigs])
    size = np.array([float(r.frame.scale) for r in rigs])
    if frames:
        rest, size = rest[:, None], size[:, None]
    return rest + moves * size[..., None, None]


@pytest.fixture(scope="module")
def rigs64():
    return star_rigs(jnp.float64)


@pytest.mark.float64
@pytest.mark.parametrize("solver", [mvcjax.FixedG(), mvcjax.GaussNewton(),
                                    mvcjax.FoldFree()], ids=lambda s: type(s).__name__)
@pytest.mark.parametrize("handles", ["points", "bone"])
def test_a_stack_poses_each_rig_as_it_poses_alone(solver, handles, rigs64):
    rigs = rigs64 if handles == "points" else star_rigs(jnp.float64, handles)
    stack = mvcjax.Rig.stack(rigs)
    assert stack.stacked == len(rigs)
    sizes = {r.shape_mesh.vertices.shape[0] for r in rigs}
    assert len(sizes) == len(rigs)  # really of different sizes
    targets = targets_for(rigs)
    out, info = jax.jit(jax.vmap(lambda r, t: r.deform(t, solver, return_info=True)))(
        stack, targets)
    assert out.shape == (len(rigs), max(sizes), 2)
    for i, rig in enumerate(rigs):
        alone, alone_info = rig.deform(targets[i], solver, return_info=True)
        n, size = alone.shape[0], float(rig.frame.scale)
        tol = 1e-12 if isinstance(solver, mvcjax.FixedG) else 1e-7
        np.testing.assert_allclose(out[i, :n], alone, atol=tol * size)
        # The padding repeats the first vertex.
        np.testing.assert_array_equal(out[i, n:], jnp.broadcast_to(out[i, 0],
                                                                   out[i, n:].shape))
        np.testing.assert_allclose(info.energy[i], alone_info.energy, rtol=1e-7,
                                   atol=1e-12 * size**2)
        assert int(info.inverted[i]) == int(alone_info.inverted)
        assert bool(info.converged[i]) == bool(alone_info.converged)
        np.testing.assert_allclose(info.handle_miss[i], alone_info.handle_miss,
                                   atol=tol * size)


def test_a_float32_stack_agrees_to_float32_rounding():
    rigs = star_rigs(jnp.float32)
    stack = mvcjax.Rig.stack(rigs)
    targets = targets_for(rigs, seed=1)
    out = jax.jit(jax.vmap(lambda r, t: r.deform(t)))(stack, targets)
    assert out.dtype == jnp.float32
    for i, rig in enumerate(rigs):
        alone = rig.deform(targets[i])
        np.testing.assert_allclose(out[i, :alone.shape[0]], alone,
                                   atol=2e-5 * float(rig.frame.scale))


@pytest.mark.float64
def test_characters_by_frames_in_one_program_without_recompiling(rigs64):
    stack = mvcjax.Rig.stack(rigs64)
    pose = jax.jit(jax.vmap(jax.vmap(lambda r, t: r.deform(t), in_axes=(None, 0))))
    targets = targets_for(rigs64, seed=2, frames=4)
    out = pose(stack, targets)
    out2 = pose(stack, targets_for(rigs64, seed=3, frames=4))
    assert pose._cache_size() == 1  # new targets, same program
    assert not np.allclose(out, out2)
    for i, rig in enumerate(rigs64):
        n = rig.shape_mesh.vertices.shape[0]
        for f in (0, 3):
            np.testing.assert_allclose(out[i, f, :n], rig.deform(targets[i, f]),
                                       atol=1e-12 * float(rig.frame.scale))


@pytest.mark.float64
def test_gradients_through_a_stack_are_each_rigs_own(rigs64):
    stack = mvcjax.Rig.stack(rigs64)
    targets = jnp.asarray(targets_for(rigs64, seed=4))
    probe = [np.random.default_rng(i).normal(size=r.shape_mesh.vertices.shape)
             for i, r in enumerate(rigs64)]
    weights = jnp.asarray(np.stack([np.pad(p, ((0, stack.shape_mesh.vertices.shape[1]
                                                - len(p)), (0, 0))) for p in probe]))

    def loss(t):
        return jnp.sum(jax.vmap(lambda r, tt: r.deform(tt))(stack, t) * weights)

    grad = jax.jit(jax.grad(loss))(targets)
    for i, rig in enumerate(rigs64):
        alone = jax.jit(jax.grad(lambda t, r, w: jnp.sum(r.deform(t) * w)))(
            targets[i], rig, jnp.asarray(probe[i]))
        np.testing.assert_allclose(grad[i], alone, rtol=1e-8, atol=1e-10)


@pytest.mark.float64
def test_a_stack_of_renderers_draws_each_picture_as_alone(rigs64):
    stack = mvcjax.Rig.stack(rigs64)
    targets = targets_for(rigs64, seed=5, frames=2)
    poses = jax.jit(jax.vmap(jax.vmap(lambda r, t: r.deform(t), in_axes=(None, 0))))(
        stack, targets)
    # Pictures of different sizes, so that the textures are padded too.
    renderers = []
    for i, rig in enumerate(rigs64):
        n = rig.shape_mesh.vertices.shape[0]
        window = mvcjax.fit_window(np.asarray(poses[i, :, :n]).reshape(-1, 2), (40, 48))
        picture = mvcjax.advanced.Checkerboard(cells=4).picture(20 + 7 * i, 30 - 4 * i)
        renderers.append(mvcjax.Renderer.build(
            rig, picture, size=(40, 48), window=window,
            image_window=np.concatenate([rig.shape_mesh.vertices.min(0) - 1,
                                         rig.shape_mesh.vertices.max(0) + 1])))
    drawn = mvcjax.Renderer.stack(renderers)
    one = jax.jit(jax.vmap(lambda r, v: r(v)))(drawn, poses[:, 0])
    many = jax.jit(jax.vmap(lambda r, f: jax.vmap(r)(f)))(drawn, poses)
    assert many.shape == (len(rigs64), 2, 40, 48, 4)
    for i, (rig, renderer) in enumerate(zip(rigs64, renderers)):
        n = rig.shape_mesh.vertices.shape[0]
        for f in range(2):
            alone = renderer(poses[i, f, :n])
            assert float(alone[..., 3].mean()) > 0.05  # something is drawn
            np.testing.assert_allclose(many[i, f], alone, atol=1e-12)
        np.testing.assert_allclose(one[i], many[i, 0], atol=1e-12)

    # Gradients by the poses are each renderer's own.
    def loss(v):
        return jnp.sum(jax.vmap(lambda r, x: r(x))(drawn, v)[..., :3] ** 2)

    grad = jax.jit(jax.grad(loss))(poses[:, 0])
    for i, (rig, renderer) in enumerate(zip(rigs64, renderers)):
        n = rig.shape_mesh.vertices.shape[0]
        alone = jax.grad(lambda v, d=renderer: jnp.sum(d(v)[..., :3] ** 2))(poses[i, 0, :n])
        np.testing.assert_allclose(grad[i, :n], alone, rtol=1e-8, atol=1e-10)
        np.testing.assert_array_equal(grad[i, n:], 0.0)


@pytest.mark.float64
def test_stacks_refuse_what_cannot_be_stacked(rigs64):
    rigs = star_rigs(jnp.float32)
    with pytest.raises(ValueError, match="same handles' layout"):
        mvcjax.Rig.stack([rigs[0], star_rigs(jnp.float32, "bone")[1]])
    with pytest.raises(ValueError, match="one dtype"):
        mvcjax.Rig.stack([rigs[0], rigs64[1]])
    with pytest.raises(ValueError, match="same skinning"):
        mvcjax.Rig.stack([rigs[0], star_rigs(jnp.float32,
                                             skinning=mvcjax.advanced.MVCSkinning())[1]])
    with pytest.raises(TypeError, match="list of rigs"):
        mvcjax.Rig.stack(rigs[0])
    with pytest.raises(TypeError, match=r"rigs\[1\] is a str"):
        mvcjax.Rig.stack([rigs[0], "rig"])
    stack = mvcjax.Rig.stack(rigs)
    with pytest.raises(ValueError, match="stack already"):
        mvcjax.Rig.stack([stack, rigs[0]])
    with pytest.raises(ValueError, match="jax.vmap"):
        stack.deform(targets_for(rigs))
    assert "a stack of 3 rigs" in repr(stack)
    small = mvcjax.Renderer.build(rigs[0], size=(16, 16))
    with pytest.raises(ValueError, match="picture size"):
        mvcjax.Renderer.stack([small, mvcjax.Renderer.build(rigs[1], size=(16, 20))])
    with pytest.raises(TypeError, match="list of renderers"):
        mvcjax.Renderer.stack(small)


def test_a_stack_padded_like_another_reuses_its_program():
    rigs = star_rigs(jnp.float32)
    big = mvcjax.Rig.stack(rigs)
    pose = jax.jit(jax.vmap(lambda r, t: r.deform(t)))
    pose(big, targets_for(rigs))
    # Another batch of as many rigs, none larger: padded like the first, one program.
    polygon = star(5, 20.0, 10.0, (3.0, 3.0))  # the first star, twice as large
    shape = mvcjax.Shape.from_polygon(polygon)
    other = mvcjax.Rig.build(shape, [tuple(3.0 + 0.3 * (p - 3.0)) for p in polygon[::2][:3]],
                             shape_spacing=shape.diagonal / 30)
    batch = [other, rigs[0], rigs[0]]
    stack = mvcjax.Rig.stack(batch, like=big)
    assert (jax.tree.map(lambda a: a.shape, stack) == jax.tree.map(lambda a: a.shape, big))
    targets = targets_for(batch, seed=6)
    out = pose(stack, targets)
    assert pose._cache_size() == 1
    for i, rig in enumerate(batch):
        alone = rig.deform(targets[i])
        np.testing.assert_allclose(out[i, :alone.shape[0]], alone,
                                   atol=2e-5 * float(rig.frame.scale))
    # Their renderers alike.
    draw = jax.jit(jax.vmap(lambda d, v: d(v)))
    drawn = mvcjax.Renderer.stack([mvcjax.Renderer.build(r, size=(24, 24)) for r in rigs])
    draw(drawn, pose(big, targets_for(rigs)))
    renderers = [mvcjax.Renderer.build(r, size=(24, 24)) for r in batch]
    like = mvcjax.Renderer.stack(renderers, like=drawn)
    pictures = draw(like, out)
    assert draw._cache_size() == 1
    for i, (rig, renderer) in enumerate(zip(batch, renderers)):
        # To float32 rounding of pixel values (see test_render.ROUNDING).
        np.testing.assert_allclose(pictures[i], renderer(out[i, :rig.shape_mesh.vertices.shape[0]]),
                                   atol=5e-5)
    with pytest.raises(ValueError, match="do not fit"):
        mvcjax.Renderer.stack([mvcjax.Renderer.build(r, size=(24, 24)) for r in rigs],
                              like=mvcjax.Renderer.stack(renderers[:1]))
    # Rigs larger than the stack given are refused, naming the sizes.
    with pytest.raises(ValueError, match="do not fit the sizes of the stack"):
        mvcjax.Rig.stack(rigs, like=mvcjax.Rig.stack([other]))
    with pytest.raises(TypeError, match="takes a stack"):
        mvcjax.Rig.stack(batch, like=other)
