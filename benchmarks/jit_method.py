"""`jax.jit(rig.deform)`: what mvcjax's bound methods (`JittableModule`, `Method`) save
over equinox's own, and the other ways to jit a rig's frame.

The ways, each timed on the default horse rig per frame (median of interleaved calls,
compiled first; the first call's time reported apart):
- `method`: `jax.jit(rig.deform)`, mvcjax's `Method`: hashed by the rig's structure and
  equal at once to the same method of the same rig;
- `equinox_method`: `jax.jit` of equinox's own bound method of the same rig (what
  `rig.deform` would be without `JittableModule.__getattribute__`): jit hashes it by its
  fields and compares every array with the cached one at each call;
- `argument`: `eqx.filter_jit(mvcjax.Rig.deform)(rig, targets)`, the rig an argument;
- `closure`: `jax.jit(lambda t: rig.deform(t))`.

    python benchmarks/jit_method.py [--quick] [--json benchmarks/results/jit_method-cpu-2core.json]
"""

from __future__ import annotations

import sys
import time

from _timing import interleaved_median_ms, quick_and_json, write_results

WAYS = ("method", "equinox_method", "argument", "closure")


def measure(repeats: int) -> list[dict]:
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import mvcjax
    from mvcjax import datasets

    rig = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles(), dtype=jnp.float32)
    targets = rig.handle_positions + jnp.asarray(datasets.horse_drag(), jnp.float32)
    equinox_deform = eqx.Module.__getattribute__(rig, "deform")
    as_argument = eqx.filter_jit(mvcjax.Rig.deform)
    ways = {
        "method": jax.jit(rig.deform),
        "equinox_method": jax.jit(equinox_deform),
        "argument": lambda t: as_argument(rig, t),
        "closure": jax.jit(lambda t: rig.deform(t)),
    }
    first = {}
    for name, fn in ways.items():
        t0 = time.perf_counter()
        jax.block_until_ready(fn(targets))
        first[name] = (time.perf_counter() - t0) * 1e3
    frames = [(targets + 0.01 * k,) for k in range(8)]
    times = interleaved_median_ms({n: (fn, frames) for n, fn in ways.items()}, repeats)
    return [{"way": name, "first_call_ms": first[name], "frame_ms": times[name],
             "over_method": times[name] / times["method"],
             "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
             "control_vertices": int(rig.control_mesh.vertices.shape[0])}
            for name in WAYS]


def format_table(data: dict) -> str:
    """The markdown table of a results file."""
    lines = ["| way | frame (ms) | over `jax.jit(rig.deform)` | first call (ms) |",
             "|---|---:|---:|---:|"]
    for row in data["rows"]:
        lines.append(f"| `{row['way']}` | {row['frame_ms']:.3f} | {row['over_method']:.2f} | "
                     f"{row['first_call_ms']:.0f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "fewer repeats", argv)
    rows = measure(40 if args.quick else 400)
    for row in rows:
        print(f"{row['way']:>15}: {row['frame_ms']:.3f} ms a frame "
              f"({row['over_method']:.2f}x jax.jit(rig.deform)), first call "
              f"{row['first_call_ms']:.0f} ms")
    if args.json:
        write_results(args.json, rows, benchmark="jit_method", quick=args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
