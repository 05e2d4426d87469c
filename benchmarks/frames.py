"""Frames per second: a batch of frames through `mvcjax.deform_frames` against a Python loop
of jitted single frames, on the horse (about 6k shape vertices, 160 control vertices).

For each batch size: compile time of the batch (its first call), the median time of a
batch over several calls (every call blocked until ready), frames per second, and the
same frames through a Python loop of a jitted single-frame `rig.deform` (dispatched
asynchronously, blocked once at the end), and the throughput ratio; and the batch with
`out=` (each call reusing the previous result's memory). With `--devices all`
the batch is sharded over every JAX device. Measured with glibc's default malloc, and
keeping freed memory for reuse (`GLIBC_TUNABLES=<_timing.KEEP_FREED_TUNABLES>`, in a
second process; `--allocator`).

    python benchmarks/frames.py                       # 1, 64, 1024, 16384 frames
    python benchmarks/frames.py --quick --json FILE   # 1, 64, 256 frames
"""

from __future__ import annotations

import argparse
import sys
import time

from _timing import allocator_rows, compile_ms, median_ms, spacing_for, write_results

COUNTS = [1, 64, 1024, 16384]
QUICK_COUNTS = [1, 64, 256]
LOOP_LIMIT = 4096  # frames: longer Python loops take too long to repeat


def run(counts, repeats: int, devices: str, chunk: int, allocator: str) -> list[dict]:
    import jax
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    shape = datasets.horse()
    rig = mvcjax.Rig.build(shape, datasets.horse_handles(), shape_spacing=spacing_for(shape, 6000))
    device_list = jax.devices() if devices == "all" else None
    single = jax.jit(lambda t: rig.deform(t))

    def loop(batch):
        return [single(t) for t in batch]

    rng = np.random.default_rng(0)
    rows = []
    for count in counts:
        batches = [
            rig.handle_positions[None]
            + rng.normal(scale=10.0, size=(count, *rig.handle_positions.shape)).astype(
                rig.handle_positions.dtype)
            for _ in range(2)
        ]
        batches = [jax.device_put(b) for b in batches]

        def batched(b):
            return mvcjax.deform_frames(rig, b, chunk=chunk, devices=device_list)

        row = {
            "frames": count,
            "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
            "control_vertices": int(rig.control_mesh.vertices.shape[0]),
            "devices": len(device_list or [0]),
            "chunk": chunk,
            "allocator": allocator,
            "batch_compile_ms": compile_ms(batched, batches[0]),
        }
        row["batch_ms"] = median_ms(batched, [(b,) for b in batches], repeats)
        row["batch_frames_per_s"] = count / row["batch_ms"] * 1e3
        if device_list is None:  # `out=`: the previous result's memory reused
            held = [batched(batches[0])]

            def into(b, held=held):
                held[0] = mvcjax.deform_frames(rig, b, chunk=chunk, out=held[0])
                return held[0]

            row["batch_out_ms"] = median_ms(into, [(b,) for b in batches], repeats)
            row["batch_out_frames_per_s"] = count / row["batch_out_ms"] * 1e3
        if count <= LOOP_LIMIT:
            single(batches[0][0]).block_until_ready()
            row["loop_ms"] = median_ms(loop, [(b,) for b in batches], max(3, repeats // 4))
            row["loop_frames_per_s"] = count / row["loop_ms"] * 1e3
            row["speedup"] = row["loop_ms"] / row["batch_ms"]
            if "batch_out_ms" in row:
                row["out_speedup"] = row["loop_ms"] / row["batch_out_ms"]
        rows.append(row)
        loop_part = (f"loop {row['loop_frames_per_s']:9.0f} frames/s, batch/loop "
                     f"{row['speedup']:5.1f}x" if "loop_ms" in row else "loop not timed")
        out_part = (f" | out= {row['batch_out_frames_per_s']:9.0f} frames/s"
                    + (f" ({row['out_speedup']:4.1f}x)" if "out_speedup" in row else "")
                    if "batch_out_ms" in row else "")
        print(f"{count:6d} frames ({allocator}): batch {row['batch_ms']:9.2f} ms = "
              f"{row['batch_frames_per_s']:9.0f} frames/s (compile {row['batch_compile_ms']:.0f} "
              f"ms) | {loop_part}{out_part}", flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small batches, few repeats")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--counts", type=int, nargs="*", help="batch sizes (frames)")
    parser.add_argument("--repeats", type=int, help="timed calls per measurement")
    parser.add_argument("--chunk", type=int, default=1024, help="frames solved together")
    parser.add_argument("--devices", choices=["one", "all"], default="one")
    parser.add_argument("--allocator", choices=["default", "keep_freed", "both"], default="both",
                        help="glibc's default malloc, one keeping freed memory "
                             "(_timing.KEEP_FREED_TUNABLES), or both")
    args = parser.parse_args(argv)
    counts = args.counts or (QUICK_COUNTS if args.quick else COUNTS)
    repeats = args.repeats or (5 if args.quick else 20)
    t0 = time.perf_counter()
    rows = allocator_rows(
        args.allocator, lambda allocator: run(counts, repeats, args.devices, args.chunk, allocator),
        __file__, sys.argv[1:] if argv is None else argv)
    print(f"total {time.perf_counter() - t0:.0f} s")
    if args.json:
        write_results(args.json, rows, benchmark="frames", repeats=repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
