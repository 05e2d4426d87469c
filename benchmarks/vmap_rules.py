"""Each second implementation mvcjax keeps for many frames, against the plain `jax.vmap`
of the single frame's path, on the default rig's horse in float32.

A second implementation stays only where it is at least 1.5 times faster than the plain
vmap (`KEEP_AT`; the single frame's own layout only needs to be faster); the tests
check that each agrees with the plain vmap to float rounding. The cases, each timed in
turns with its plain counterpart (compiled first, medians of calls blocked until ready):

- `skinning`: `jax.vmap(rig.skinning)` over control vertices, whose rule is one batched
  product over blocks of consecutive shape vertices with frames as the product's rows
  (the layout `(c, 2f)`), against JAX's batching of the single frame's packed skinning.
- `fixed_g`: `jax.vmap` of FixedG's solve over targets, whose rule steps all frames
  together laid out `(n, 2, f)` (the dense factor's `step_frames`: one product
  `N^{-1} (A^T W b)` for every frame), against JAX's batching of the single frame's loop;
  `fixed_g_few`: the same at 4 frames, where the rule is slower (needed: below 1), so
  that FixedG leaves fewer than `FEWEST_FRAMES_STEPPED_TOGETHER` frames to JAX.
- `skin_into`: `deform_frames(out=)`'s skinning into a donated array, a group of frames
  a product, against the plain vmap written into a donated array.
- `render`: `jax.vmap(renderer)` over poses, whose rule draws one frame after another
  inside one program (`lax.map`), against JAX's batching of the single frame's
  drawing, at 512 x 512 pixels (128 x 128 in the quick run), a few frames.
- `frame_layout`: one frame's fixed-G solve in the single-frame layout, coordinate rows
  `(2, n)` with `G b` as one product, against the same solve through the many-frames
  layout with one frame, `(n, 2, 1)`: the reason the single frame keeps its own layout.

    python benchmarks/vmap_rules.py [--quick] [--json benchmarks/results/vmap_rules-cpu-2core.json]
"""

from __future__ import annotations

import sys

from _timing import interleaved_median_ms, quick_and_json, spacing_for, write_results

KEEP_AT = 1.5
# The single frame's own layout needs only to be faster than the alternative.
KEEP_LAYOUT_AT = 1.0
SIZES, QUICK_SIZES = [6000, 20000], [1500, 6000]
FRAMES, QUICK_FRAMES = 256, 32
RENDER_FRAMES, RENDER_SIZE, QUICK_RENDER_SIZE = 8, 512, 128
FEW_FRAMES = 4


def _cases(rig, frames: int, picture_size: int) -> dict:
    """`{case: (second implementation, plain, args)}`, each a compiled function."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import mvcjax
    from mvcjax import datasets
    from mvcjax.core._batching import with_batching_rule
    from mvcjax.geometry import _skinning
    from mvcjax.rendering import _render

    rest = np.asarray(rig.handle_positions)
    scale = np.random.default_rng(0).uniform(0.2, 1.0, size=(frames, 1, 1))
    targets = jnp.asarray(rest + scale * np.asarray(datasets.horse_drag()), jnp.float32)
    solver = mvcjax.FixedG()
    local = jax.vmap(rig.frame.to_local)(targets)
    pinned = jax.vmap(rig.handles.pinned_targets)(local)
    starts = jax.vmap(lambda t: rig._local_start(t, mvcjax.advanced.TurnedStart()))(local)

    def solve_with(fn, count=frames):
        solve = jax.jit(jax.vmap(lambda p, s: fn(rig.energy, rig.factor, p, s)[0]))
        return lambda p, s: solve(p[:count], s[:count])

    # The rule itself, stepping all frames together at any count (`solver.solve` leaves
    # fewer than FEWEST_FRAMES_STEPPED_TOGETHER to JAX's batching).
    rule = with_batching_rule(solver._iterate, solver._iterate_frames)

    control = solve_with(solver.solve)(pinned, starts)
    skinning, frame = rig.skinning, rig.frame
    out = jnp.zeros((frames, *rig.shape_mesh.vertices.shape), jnp.float32)
    into = jax.jit(_skinning.skin_frames_into, donate_argnums=3)
    plain_into = jax.jit(
        lambda v, o: o.at[:].set(jax.vmap(lambda c: _skinning._skin_in(skinning, c, frame))(v)),
        donate_argnums=1)
    state = {"into": out, "plain_into": out + 0}

    def donated(name, fn):
        def call(v):
            state[name] = fn(v, state[name])
            return state[name]
        return call

    one = (pinned[0], starts[0])
    picture = np.random.default_rng(1).uniform(size=(picture_size, picture_size, 4))
    picture[..., 3] = 1.0
    renderer = mvcjax.Renderer.build(rig, picture.astype(np.float32))
    poses = jax.vmap(lambda v: skinning(v, frame))(control[:RENDER_FRAMES])
    return {
        "skinning": (jax.jit(jax.vmap(lambda v: skinning(v, frame))),
                     jax.jit(jax.vmap(lambda v: _skinning._skin_in(skinning, v, frame))),
                     (control,)),
        "fixed_g": (solve_with(rule), solve_with(solver._iterate), (pinned, starts)),
        "fixed_g_few": (solve_with(rule, FEW_FRAMES), solve_with(solver._iterate, FEW_FRAMES),
                        (pinned, starts)),
        "skin_into": (donated("into", lambda v, o: into(skinning, v, frame, o)),
                      donated("plain_into", plain_into), (control,)),
        "render": (jax.jit(jax.vmap(renderer)),
                   jax.jit(jax.vmap(lambda v: _render._draw(renderer, v, renderer.window))),
                   (poses,)),
        # Reversed: the kept implementation is the single frame's own layout.
        "frame_layout": (
            jax.jit(lambda p, s: solver._iterate(rig.energy, rig.factor, p, s)[0]),
            jax.jit(lambda p, s: jax.vmap(lambda p, s: rule(
                rig.energy, rig.factor, p, s)[0])(p[None], s[None])[0]),
            one),
    }


def measure(sizes, frames: int, repeats: int, picture_size: int = RENDER_SIZE) -> list[dict]:
    import jax.numpy as jnp
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    shape, handles = datasets.horse(), datasets.horse_handles()
    rows = []
    for target in sizes:
        rig = mvcjax.Rig.build(shape, handles, shape_spacing=spacing_for(shape, target),
                               dtype=jnp.float32)
        cases = _cases(rig, frames, picture_size)
        for name, (kept, plain, args) in cases.items():
            error = float(np.max(np.abs(np.asarray(kept(*args)) - np.asarray(plain(*args)))))
            times = interleaved_median_ms({"kept": (kept, [args]), "plain": (plain, [args])},
                                          repeats)
            # Where the kept choice is not a rule: the single frame's layout, and JAX's
            # batching for a few frames (`kept` the rule then, and it must be slower).
            keep_at = {"frame_layout": KEEP_LAYOUT_AT, "fixed_g_few": None}.get(name, KEEP_AT)
            rows.append({
                "case": name,
                "target_shape_vertices": target,
                "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                "frames": {"frame_layout": 1, "render": RENDER_FRAMES,
                           "fixed_g_few": FEW_FRAMES}.get(name, frames),
                "kept_ms": times["kept"],
                "plain_ms": times["plain"],
                "speedup": times["plain"] / times["kept"],
                "keep_at": keep_at,
                "kept_is_faster_enough": None if keep_at is None
                else times["plain"] / times["kept"] >= keep_at,
                "max_difference": error,
            })
    return rows


def format_table(data: dict) -> str:
    """The markdown table of a results file."""
    lines = ["| case | shape vertices | frames | kept (ms) | plain (ms) | plain / kept | "
             "needed |", "|---|---:|---:|---:|---:|---:|---:|"]
    for row in data["rows"]:
        lines.append(f"| `{row['case']}` | {row['shape_vertices']} | {row['frames']} | "
                     f"{row['kept_ms']:.3f} | {row['plain_ms']:.3f} | {row['speedup']:.2f} | "
                     + (f"{row['keep_at']:.1f} |" if row["keep_at"] else "below 1 |"))
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "smaller meshes, fewer frames and repeats", argv)
    rows = measure(QUICK_SIZES if args.quick else SIZES,
                   QUICK_FRAMES if args.quick else FRAMES, 20 if args.quick else 100,
                   QUICK_RENDER_SIZE if args.quick else RENDER_SIZE)
    for row in rows:
        print(f"{row['case']:>13} at {row['shape_vertices']:>6} vertices, {row['frames']:>4} "
              f"frames: kept {row['kept_ms']:.3f} ms, plain {row['plain_ms']:.3f} ms "
              f"({row['speedup']:.2f}x; max difference {row['max_difference']:.1e})")
    if args.json:
        write_results(args.json, rows, benchmark="vmap_rules", quick=args.quick, keep_at=KEEP_AT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
