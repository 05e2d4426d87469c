"""The bound on the compiled programs kept: past `SIZES_KEPT` rig sizes, JAX's caches are
cleared, and every rig alive still poses as before."""

import jax
import numpy as np

import mvcjax
from mvcjax.rig import _programs


def star(points, outer=60.0, inner=30.0):
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False)
    r = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)


def rig_of(polygon):
    shape = mvcjax.Shape.from_polygon(polygon)
    return mvcjax.Rig.build(shape, [tuple(p) for p in polygon[::2][:3] * 0.3],
                            shape_spacing=shape.diagonal / 12)


def test_past_the_budget_the_caches_are_cleared_and_rigs_still_pose(monkeypatch):
    cleared = []
    clear = jax.clear_caches
    monkeypatch.setattr(_programs, "SIZES_KEPT", 2)
    monkeypatch.setattr(_programs, "_sizes", set())
    monkeypatch.setattr(jax, "clear_caches", lambda: (cleared.append(1), clear()))
    first = rig_of(star(5))
    targets = first.handle_positions + 3.0
    before = np.asarray(first.deform(targets))
    # The same star again: the same size, nothing new to keep.
    again = rig_of(star(5))
    assert _programs.size_of(again) == _programs.size_of(first)
    rig_of(star(7))
    assert cleared == []  # two sizes: within the budget
    rig_of(star(9))
    assert cleared == [1]  # a third: the caches were cleared first
    assert len(_programs._sizes) == 1
    # The first rig compiles anew and poses exactly as before.
    np.testing.assert_array_equal(np.asarray(first.deform(targets)), before)


def test_building_a_rig_and_a_renderer_of_new_sizes_compiles_a_few_programs(caplog,
                                                                           monkeypatch):
    # Sizes counted from here: the budget, full from earlier tests, would clear JAX's
    # caches inside a build, which then compiles again what any program needs.
    monkeypatch.setattr(_programs, "_sizes", set())

    # The build's JAX work runs as a few compiled programs, not as dozens of eager
    # operations each compiled anew for every new size (or arrays staged by jnp.asarray).
    def build(points, fineness):
        shape = mvcjax.Shape.from_polygon(star(points))
        return mvcjax.Rig.build(shape, [(0.0, 0.0), (20.0, 5.0)],
                                shape_spacing=shape.diagonal / fineness)

    mvcjax.Renderer.build(build(5, 10), size=(32, 32))
    sizes = set()
    for points, fineness in [(7, 14), (9, 17)]:
        with jax.log_compiles(True), caplog.at_level("WARNING"):
            caplog.clear()
            rig = build(points, fineness)
            built = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
            caplog.clear()
            mvcjax.Renderer.build(rig, size=(32 + points, 32 + points))
            drawn = [r.getMessage() for r in caplog.records if "Compiling" in r.getMessage()]
        sizes.add(rig.shape_mesh.faces.shape)
        assert 1 <= len(built) <= 2, built
        assert 1 <= len(drawn) <= 2, drawn
    assert len(sizes) == 2  # new sizes each time
