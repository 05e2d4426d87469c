"""What a rig compiles belongs to it: shared by the rigs of its size alive, gone with the
last of them (once `RECENT` newer programs have run), and nothing else of the process
touched (the user's own compiled functions stay compiled)."""

import contextlib
import copy
import gc
import pickle
import weakref

import jax
import jax.numpy as jnp
import numpy as np

import mvcjax
from mvcjax.core import _programs


def star(points, outer=60.0, inner=30.0):
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False)
    r = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)


def build(points, fineness=10):
    shape = mvcjax.Shape.from_polygon(star(points))
    return mvcjax.Rig.build(shape, [(0.0, 0.0), (20.0, 5.0)],
                            shape_spacing=shape.diagonal / fineness)


@contextlib.contextmanager
def compiling(caplog):
    """The names of the programs compiled inside the block, in the list it yields."""
    names = []
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        caplog.clear()
        yield names
        names += [r.getMessage().split()[1] for r in caplog.records
                  if r.getMessage().startswith("Compiling")]


def maps() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


def resident_mb() -> float:
    with open("/proc/self/status") as f:
        line = next(line for line in f if line.startswith("VmRSS"))
    return int(line.split()[1]) / 1024


def pose(rig):
    return rig.deform(rig.handle_positions + 2.0)


def test_rigs_of_one_size_share_programs_and_a_rig_keeps_its_own(caplog):
    first = build(5)
    before = np.asarray(pose(first))
    # Another rig of the same size, alive beside the first: nothing new to compile.
    with compiling(caplog) as compiled:
        pose(build(5))
    assert compiled == []
    # Rigs of other sizes come and go; the first keeps its programs and poses as before.
    for points in (6, 7):
        pose(build(points))
    with compiling(caplog) as compiled:
        again = np.asarray(pose(first))
    assert compiled == []
    np.testing.assert_array_equal(again, before)


def test_a_rig_built_compiles_a_few_programs_and_its_renderer_a_few_more(caplog):
    # The build's JAX work runs as a few compiled programs, not as dozens of eager
    # operations each compiled anew for every new size (or arrays staged by jnp.asarray).
    mvcjax.Renderer.build(build(5), size=(32, 32))
    sizes = set()
    for points, fineness in [(7, 14), (9, 17)]:
        with compiling(caplog) as built:
            rig = build(points, fineness)
        with compiling(caplog) as drawn:
            mvcjax.Renderer.build(rig, size=(32 + points, 32 + points))
        sizes.add(rig.shape_mesh.faces.shape)
        assert 1 <= len(built) <= 2, built
        assert 1 <= len(drawn) <= 2, drawn
    assert len(sizes) == 2  # new sizes each time


def test_an_eager_gradient_compiles_the_rigs_program_differentiated_not_each_operation(caplog):
    rig = build(6)
    targets = rig.handle_positions + 2.0
    pose(rig)

    def loss(t):
        return jnp.sum(rig.deform(t) ** 2)

    with compiling(caplog) as compiled:
        eager = jax.grad(loss)(targets)
    assert 1 <= len(compiled) <= 20, compiled  # run op by op: hundreds
    with compiling(caplog) as compiled:
        again = jax.grad(loss)(targets + 1.0)
    assert compiled == []  # new targets, the same programs
    np.testing.assert_allclose(eager, jax.jit(jax.grad(loss))(targets), rtol=1e-4,
                               atol=1e-5 * float(jnp.abs(eager).max()))
    assert not np.allclose(again, eager)


def test_a_start_and_a_skin_are_a_program_each_eagerly(caplog):
    # Outside jit, a rig's start (the turned start's dozens of operations) and its
    # skinning run as one compiled program each, as its solve does, reused for new
    # targets; the same numbers as under jit.
    rig = build(7)
    targets = rig.handle_positions + 2.0
    with compiling(caplog) as compiled:
        start = rig.start(targets)
        skinned = rig.skin(start)
    assert 1 <= len(compiled) <= 4, compiled  # op by op: over a hundred
    with compiling(caplog) as compiled:
        rig.skin(rig.start(targets + 1.0))
    assert compiled == []
    np.testing.assert_allclose(start, jax.jit(rig.start)(targets), rtol=0, atol=1e-5)
    np.testing.assert_allclose(skinned, jax.jit(rig.skin)(start), rtol=0, atol=1e-5)


def test_an_eager_vmap_over_a_stack_compiles_its_program_batched(caplog):
    # Outside jit, jax.vmap of a rig's deform over a stack of rigs runs the rig's
    # program batched whole, not each operation as a program of its own.
    stack = mvcjax.Rig.stack([build(5), build(6)])
    targets = stack.handle_positions + 2.0
    with compiling(caplog) as compiled:
        posed = jax.vmap(lambda r, t: r.deform(t))(stack, targets)
    assert 1 <= len(compiled) <= 8, compiled  # op by op, each operation would be one
    np.testing.assert_allclose(posed, jax.jit(jax.vmap(lambda r, t: r.deform(t)))(
        stack, targets), rtol=0, atol=1e-4)


def test_programs_go_with_the_last_rig_of_their_size(caplog, monkeypatch):
    monkeypatch.setattr(_programs, "RECENT", 0)  # none kept after their rigs
    rig = build(11, 13)
    pose(rig)
    with compiling(caplog) as compiled:
        pose(rig)
    assert compiled == []
    del rig
    gc.collect()
    # Nothing kept them: a new rig of that size compiles them again.
    with compiling(caplog) as compiled:
        pose(build(11, 13))
    assert "jit(_deform)" in compiled


def rigs_of_new_sizes(count):
    """Build, pose and drop `count` rigs, each of a size no other had; the memory maps
    and resident memory after each."""
    seen, counts, fineness = set(), [], 8.0
    while len(counts) < count:
        fineness += 0.25
        rig = build(5, fineness)
        if rig.shape_mesh.vertices.shape in seen:
            continue
        seen.add(rig.shape_mesh.vertices.shape)
        pose(rig)
        del rig
        gc.collect()
        counts.append((maps(), resident_mb()))
    return counts


def test_rigs_of_new_sizes_keep_no_programs_and_leave_the_users_compiled(caplog, monkeypatch):
    count = 16
    monkeypatch.setattr(_programs, "RECENT", 4)
    # The user's own jitted function, compiled before: it is not compiled again after.
    user = jax.jit(lambda x: x * 2.0 + 1.0)
    user(np.ones(3, np.float32))
    counts = rigs_of_new_sizes(count)
    with compiling(caplog) as compiled:
        user(np.ones(3, np.float32))
    assert compiled == []
    # Bounded: the last rigs leave no more memory maps or memory than the first ones.
    half = count // 2
    first_maps = max(m for m, _ in counts[:half])
    first_mb = max(mb for _, mb in counts[:half])
    assert max(m for m, _ in counts[half:]) <= first_maps + 40, counts
    assert max(mb for _, mb in counts[half:]) <= first_mb + 100, counts


def test_what_a_rig_keeps_is_no_part_of_its_pytree():
    rig = build(5)
    pose(rig)
    assert len(rig.programs._ran) > 0
    # No leaves, equal structures; transformations and copies carry the rig, not its
    # programs' identity in any structure.
    assert not any(isinstance(leaf, _programs.Programs) for leaf in jax.tree.leaves(rig))
    assert jax.tree.structure(rig) == jax.tree.structure(build(5))
    assert jax.tree.map(lambda a: a, rig).programs is rig.programs
    for copied in (copy.deepcopy(rig), pickle.loads(pickle.dumps(rig))):
        assert copied.programs is not rig.programs and not copied.programs._ran
        np.testing.assert_array_equal(np.asarray(pose(copied)), np.asarray(pose(rig)))
    # Nothing else holds it: it goes with the rig.
    programs = weakref.ref(rig.programs)
    del rig
    gc.collect()
    assert programs() is None
