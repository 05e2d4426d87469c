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
  `N^{-1} (A^T W b)` for every frame), against JAX's batching of the single frame's loop.
- `skin_into`: `deform_frames(out=)`'s skinning into a donated array, a group of frames
  a product, against the plain vmap written into a donated array.
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


def _cases(rig, frames: int) -> dict:
    """`{case: (second implementation, plain, args)}`, each a compiled function."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import mvcjax
    from mvcjax import _skinning, datasets

    rest = np.asarray(rig.handle_positions)
    scale = np.random.default_rng(0).uniform(0.2, 1.0, size=(frames, 1, 1))
    targets = jnp.asarray(rest + scale * np.asarray(datasets.horse_drag()), jnp.float32)
    solver = mvcjax.FixedG()
    local = jax.vmap(rig.frame.to_local)(targets)
    pinned = jax.vmap(rig.handles.pinned_targets)(local)
    starts = jax.vmap(lambda t: rig._local_start(t, "turned"))(local)

    def solve_with(fn):
        return jax.jit(jax.vmap(lambda p, s: fn(rig.energy, rig.factor, p, s)[0]))

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
    return {
        "skinning": (jax.jit(jax.vmap(lambda v: skinning(v, frame))),
                     jax.jit(jax.vmap(lambda v: _skinning._skin_in(skinning, v, frame))),
                     (control,)),
        "fixed_g": (solve_with(solver.solve), solve_with(solver._iterate), (pinned, starts)),
        "skin_into": (donated("into", lambda v, o: into(skinning, v, frame, o)),
                      donated("plain_into", plain_into), (control,)),
        # Reversed: the kept implementation is the single frame's own layout.
        "frame_layout": (
            jax.jit(lambda p, s: solver._iterate(rig.energy, rig.factor, p, s)[0]),
            jax.jit(lambda p, s: jax.vmap(lambda p, s: solver.solve(
                rig.energy, rig.factor, p, s)[0])(p[None], s[None])[0]),
            one),
    }


def measure(sizes, frames: int, repeats: int) -> list[dict]:
    import jax.numpy as jnp
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    shape, handles = datasets.horse(), datasets.horse_handles()
    rows = []
    for target in sizes:
        rig = mvcjax.Rig.build(shape, handles, shape_spacing=spacing_for(shape, target),
                               dtype=jnp.float32)
        cases = _cases(rig, frames)
        for name, (kept, plain, args) in cases.items():
            error = float(np.max(np.abs(np.asarray(kept(*args)) - np.asarray(plain(*args)))))
            times = interleaved_median_ms({"kept": (kept, [args]), "plain": (plain, [args])},
                                          repeats)
            keep_at = KEEP_LAYOUT_AT if name == "frame_layout" else KEEP_AT
            rows.append({
                "case": name,
                "target_shape_vertices": target,
                "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                "frames": 1 if name == "frame_layout" else frames,
                "kept_ms": times["kept"],
                "plain_ms": times["plain"],
                "speedup": times["plain"] / times["kept"],
                "keep_at": keep_at,
                "kept_is_faster_enough": times["plain"] / times["kept"] >= keep_at,
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
                     f"{row['keep_at']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "smaller meshes, fewer frames and repeats", argv)
    rows = measure(QUICK_SIZES if args.quick else SIZES,
                   QUICK_FRAMES if args.quick else FRAMES, 20 if args.quick else 100)
    for row in rows:
        print(f"{row['case']:>13} at {row['shape_vertices']:>6} vertices, {row['frames']:>4} "
              f"frames: kept {row['kept_ms']:.3f} ms, plain {row['plain_ms']:.3f} ms "
              f"({row['speedup']:.2f}x; max difference {row['max_difference']:.1e})")
    if args.json:
        write_results(args.json, rows, benchmark="vmap_rules", quick=args.quick, keep_at=KEEP_AT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
