"""The as-rigid-as-possible term (`Weights(arap=...)`): the energy it measures, libigl's
ARAP as its oracle, every solver on it, its gradients, and what it does to a bend."""

import igl
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mvcjax
from mvcjax import datasets

ARAP_ONLY = dict(laplacian=None, mvc=None, length=None, arap=1.0)


def _small_full_rig(horse, handle, dtype=jnp.float64):
    """The horse's shape mesh itself as the control mesh (a few hundred vertices),
    holding only the ARAP term and the handles."""
    return mvcjax.Rig.build(horse, datasets.horse_handles(), control=mvcjax.FullSolve(),
                            shape_spacing=18.0, dtype=dtype,
                            weights=mvcjax.Weights(**ARAP_ONLY, handle=handle))


def _libigl(rig, iterations):
    """libigl's ARAP (elements energy) on the rig's shape mesh, its handles held fixed:
    `solve(pinned targets, start)`."""
    mesh = rig.shape_mesh
    data = igl.ARAPData()
    data.max_iter = iterations
    data.energy = igl.ARAP_ENERGY_TYPE_ELEMENTS
    handles = np.asarray(mesh.handles, np.int32)
    igl.arap_precomputation(np.asarray(mesh.vertices, np.float64),
                            np.asarray(mesh.faces, np.int64), 2, handles, data)
    return lambda pinned, start: igl.arap_solve(np.ascontiguousarray(pinned, np.float64), data,
                                                np.ascontiguousarray(start, np.float64))


@pytest.mark.float64
def test_fixed_g_on_the_arap_term_is_libigls_arap(horse):
    # FixedG's local-global steps on the term alone are libigl's ARAP iteration: the
    # same iterates from the same start, and the same minimum. libigl holds the handles
    # exactly; here a handle weight 1e5 times the term's holds them to 1e-7 of the
    # diagonal. (At 1e6 or more, Gauss-Newton's steps stop at float64's rounding floor
    # of this stiff problem, and whether it claims convergence hangs on that rounding.)
    rig = _small_full_rig(horse, 1e5)
    targets = rig.handle_positions + datasets.horse_drag()
    pinned = np.asarray(rig.pinned_targets(targets))
    start = np.array(rig.start(targets))
    start[np.asarray(rig.shape_mesh.handles)] = pinned
    diagonal = float(rig.frame.scale)
    for steps in (1, 15):
        ours = rig.solve(targets, mvcjax.FixedG(iterations=steps), init=start)
        reference = _libigl(rig, steps)(pinned, start)
        assert np.abs(np.asarray(ours) - reference).max() < 1e-6 * diagonal, steps
    reference = _libigl(rig, 16000)(pinned, start)  # ARAP converges slowly
    ours, info = rig.solve(targets, mvcjax.GaussNewton(max_steps=500), init=start,
                           return_info=True)
    assert bool(info.converged)
    assert np.abs(np.asarray(ours) - reference).max() < 1e-6 * diagonal
    moved = np.abs(reference - np.asarray(rig.shape_mesh.vertices)).max()
    assert moved > 0.05 * diagonal  # a real deformation, not the rest pose


@pytest.mark.float64
def test_the_term_is_the_area_weighted_distance_to_the_nearest_rotation(horse):
    # Independently of the stencils: per triangle, area * |J - R|^2 with J from the
    # rest and current edges and R the rotation nearest to it, and the cotangent form libigl
    # minimises, sum over edges of cot(opposite angle) / 2 * |e - R e_rest|^2.
    rig = _small_full_rig(horse, 100.0)
    energy = rig.energy
    rest, faces = np.asarray(energy.rest), np.asarray(energy.faces)
    rng = np.random.default_rng(0)
    current = rest + 0.003 * rng.standard_normal(rest.shape)
    term = next(t for t in energy.terms() if t.name == "arap")
    ours = float(jnp.sum(term.residual(jnp.asarray(current), None) ** 2))

    def edges(v):
        c = v[faces]
        return np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], axis=2)  # (f, 2, 2)

    rest_edges, current_edges = edges(rest), edges(current)
    gradient = current_edges @ np.linalg.inv(rest_edges)
    # The rotation nearest to J (reflections excluded): its angle maximises tr(R^T J).
    angle = np.arctan2(gradient[:, 1, 0] - gradient[:, 0, 1], gradient[:, 0, 0] + gradient[:, 1, 1])
    nearest = np.stack([np.stack([np.cos(angle), -np.sin(angle)], 1),
                        np.stack([np.sin(angle), np.cos(angle)], 1)], 1)
    area = 0.5 * np.linalg.det(rest_edges)
    by_gradient = float(np.sum(area * np.sum((gradient - nearest) ** 2, axis=(1, 2))))
    corners_rest, corners = rest[faces], current[faces]
    by_cotangent = 0.0
    for k in range(3):
        i, j, o = k, (k + 1) % 3, (k + 2) % 3
        a, b = corners_rest[:, i] - corners_rest[:, o], corners_rest[:, j] - corners_rest[:, o]
        cot = np.sum(a * b, axis=1) / (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        miss = (corners[:, i] - corners[:, j]) - np.einsum(
            "fab,fb->fa", nearest, corners_rest[:, i] - corners_rest[:, j])
        by_cotangent += float(np.sum(0.5 * cot * np.sum(miss**2, axis=1)))
    assert ours == pytest.approx(by_gradient, rel=1e-10)
    assert ours == pytest.approx(by_cotangent, rel=1e-10)


SOLVERS = [mvcjax.GaussNewton(max_steps=500), mvcjax.LevenbergMarquardt(max_steps=500),
           mvcjax.Dogleg(max_steps=500)]


@pytest.mark.float64
@pytest.mark.parametrize("weights", [ARAP_ONLY, {}, dict(laplacian=1.0, mvc=1.0, length=1.0,
                                                          arap=10.0)],
                         ids=["alone", "default", "mixed"])
@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: type(s).__name__)
def test_every_solver_reaches_fixed_gs_minimum(horse, weights, solver):
    # The term is declared once (rows, rest vectors, groups): the fixed-G local step,
    # the residuals and the structured Gauss-Newton matrix all follow from it, so the
    # solvers agree to their tolerance, on the term alone and mixed with the paper's.
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64,
                           weights=mvcjax.Weights(**weights))
    targets = rig.handle_positions + datasets.horse_drag()
    reference, ref_info = rig.solve(targets, mvcjax.FixedG(
        iterations=20000, anderson=5, stop_early=True, rtol=1e-10), return_info=True)
    assert bool(ref_info.converged)
    vertices, info = rig.solve(targets, solver, return_info=True)
    assert bool(info.converged)
    assert float(info.energy) == pytest.approx(float(ref_info.energy), rel=1e-8)
    np.testing.assert_allclose(vertices, reference, atol=1e-6 * float(rig.frame.scale))


@pytest.mark.float64
def test_gradients_through_the_term_match_finite_differences(horse):
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64,
                           weights=mvcjax.Weights(1.0, 1.0, 1.0, arap=10.0))
    targets = rig.handle_positions + datasets.horse_drag()

    def pose(t, arap):
        posed = rig.with_weights(mvcjax.Weights(1.0, 1.0, 1.0, arap=arap))
        return jnp.sum(posed.deform(t)[::50] ** 2)

    arap = jnp.asarray(10.0)
    by_target, by_weight = jax.grad(pose, argnums=(0, 1))(targets, arap)
    step = 1e-4
    direction = np.zeros(np.shape(targets))
    direction[0] = [1.0, -0.5]
    central = (pose(targets + step * direction, arap)
               - pose(targets - step * direction, arap)) / (2 * step)
    assert float(jnp.sum(by_target * direction)) == pytest.approx(float(central), rel=1e-6)
    central = (pose(targets, arap + step) - pose(targets, arap - step)) / (2 * step)
    assert float(by_weight) == pytest.approx(float(central), rel=1e-5)
    assert abs(float(by_weight)) > 0


def test_a_new_arap_weight_compiles_nothing_new(horse):
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), weights=mvcjax.Weights(arap=1.0))
    targets = rig.handle_positions + datasets.horse_drag()
    deform = jax.jit(lambda w, t: rig.with_weights(mvcjax.Weights(arap=w)).deform(t))
    first = deform(1.0, targets)
    second = deform(30.0, targets)
    assert deform._cache_size() == 1
    assert np.isfinite(np.asarray(second)).all()
    assert np.abs(np.asarray(second) - np.asarray(first)).max() > 1e-3


# A power of two and a whole offset: Triangle then meshes the same numbers (its
# refinement turns a last-bit difference into another mesh).
@pytest.mark.parametrize("dtype", [jnp.float32,
                                   pytest.param(jnp.float64, marks=pytest.mark.float64)])
def test_arap_rigs_do_not_depend_on_where_the_shape_sits(horse, dtype):
    weights = mvcjax.Weights()
    offset = np.array([64.0, -32.0])

    def place(p):
        return np.asarray(p) * 2.0**-4 + offset

    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), weights=weights, dtype=dtype)
    moved = mvcjax.Rig.build(mvcjax.Shape.from_polygon(place(horse.outer)),
                             place(datasets.horse_handles()), weights=weights, dtype=dtype)
    assert moved.shape_mesh.vertices.shape == rig.shape_mesh.vertices.shape
    targets = rig.handle_positions + datasets.horse_drag()
    posed = np.asarray(rig.deform(targets))
    moved_posed = (np.asarray(moved.deform(place(targets))) - offset) * 2.0**4
    tolerance = (1e-4 if dtype == jnp.float32 else 1e-9) * float(rig.frame.scale)
    assert np.abs(moved_posed - posed).max() < tolerance
    assert np.abs(posed - np.asarray(rig.shape_mesh.vertices)).max() > 0.05 * float(
        rig.frame.scale)


@pytest.mark.parametrize("weights", [dict(arap=10.0),
                                     dict()],
                         ids=["mixed", "alone"])
def test_the_term_in_a_stack_and_a_ladder(horse, weights):
    # A stack pads the control triangles with degenerate ones, whose rows are zero, and
    # a laddered rig's twin likewise: each rig poses as alone.
    weights = mvcjax.Weights(**weights)
    shapes = [datasets.glyph(c) for c in "HK"]
    rigs = [mvcjax.Rig.build(s, np.concatenate(datasets.glyph_handles(s)), weights=weights)
            for s in shapes]
    stack = mvcjax.Rig.stack(rigs)
    targets = jnp.stack([r.handle_positions + jnp.asarray([[0.0, 30.0]] * 3 + [[0.0, 0.0]] * 3)
                         for r in rigs])
    posed = jax.vmap(lambda r, t: r.deform(t))(stack, targets)
    for i, (shape, rig) in enumerate(zip(shapes, rigs)):
        alone = np.asarray(rig.deform(targets[i]))
        tolerance = 1e-4 * float(rig.frame.scale)
        assert np.abs(np.asarray(posed[i, :len(alone)]) - alone).max() < tolerance
        laddered = mvcjax.Rig.build(shape, np.concatenate(datasets.glyph_handles(shape)),
                                    weights=weights, ladder=mvcjax.SizeLadder())
        assert np.abs(np.asarray(laddered.deform(targets[i])) - alone).max() < tolerance
        assert np.abs(alone - np.asarray(rig.shape_mesh.vertices)).max() > 10.0


def test_stacks_and_ladders_need_the_mean_value_rows(horse):
    weights = mvcjax.Weights(laplacian=None, mvc=None, length=None, arap=1.0)
    rig = mvcjax.Rig.build(horse, datasets.horse_handles(), weights=weights)
    with pytest.raises(ValueError, match=r"small one, as the default's, bends nothing"):
        mvcjax.Rig.stack([rig, rig])
    with pytest.raises(ValueError, match=r"small one, as the default's, bends nothing"):
        mvcjax.Rig.build(horse, datasets.horse_handles(), weights=weights,
                         ladder=mvcjax.SizeLadder())


@pytest.mark.float64
def test_with_weights_that_change_the_terms_rebuilds_the_rows(horse):
    # From the paper's energy to the ARAP term and back: a rig rebuilt with other terms
    # deforms as one built with them (its local rows made anew, not reused); under jit,
    # where the rows cannot be made anew, the change is refused with the fix.
    paper = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64,
                             weights=mvcjax.Weights.paper())
    rigid = mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64)
    targets = paper.handle_positions + datasets.horse_drag()
    for start, goal, weights in [(paper, rigid, mvcjax.Weights()),
                                 (rigid, paper, mvcjax.Weights.paper())]:
        np.testing.assert_allclose(start.with_weights(weights).deform(targets),
                                   goal.deform(targets), atol=1e-9 * float(paper.frame.scale))
    with pytest.raises(ValueError, match="outside the transformation"):
        jax.jit(lambda w: paper.with_weights(mvcjax.Weights(arap=w)).deform(targets))(1.0)


def test_fold_free_on_the_default_energy_unfolds_what_it_folds():
    # The character's right arm turned 180 degrees about the shoulder: the default
    # energy's pose still folds a few triangles by the armpit (the control mesh's
    # limit, libigl's ARAP on it folds there too); FoldFree, on the same energy, none.
    model = datasets.model("character")
    rig = mvcjax.Rig.build(model.shape, datasets.character_bones("arms"), **model.options)
    targets = np.array(rig.handle_positions)
    shoulder, wrist = targets[4], targets[5]
    targets[5] = 2 * shoulder - wrist  # turned 180 degrees about the shoulder
    mesh = rig.shape_mesh
    folded = rig.deform(targets)
    assert mvcjax.flipped_triangles(mesh.vertices, folded, mesh.faces) > 0  # the trap
    unfolded, info = rig.deform(targets, mvcjax.FoldFree(), return_info=True)
    assert mvcjax.flipped_triangles(mesh.vertices, unfolded, mesh.faces) == 0
    assert int(info.inverted) == 0
    assert float(info.handle_miss) < 0.05 * float(rig.frame.scale)
