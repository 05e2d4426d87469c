"""Many rigs of different sizes in one process: memory maps and resident memory as the
rigs go by, and the time of a new rig's build and first frame, for a size whose
programs are compiled and for a new one.

Stars of 5 to 11 points and random radii, meshed at a sixtieth of their diagonal (about
1,000 to 1,800 shape vertices), each built and posed once (`rig.deform`), one after
another, as a script that rigs every glyph of a font does. mvcjax keeps the programs of
at most `mvcjax._programs.SIZES_KEPT` rig sizes (`_programs` says why and how); the
maps and the resident memory are read from `/proc/self` every 10 rigs, over 1,000 rigs.

    python benchmarks/many_rigs.py [--quick] [--json benchmarks/results/many_rigs-cpu-2core.json]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from _timing import quick_and_json, write_results


def star(points: int, outer: float, inner: float) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 2 * points, endpoint=False)
    r = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1)


def memory_maps() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


def resident_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


def posed(polygon: np.ndarray):
    """Build a rig of `polygon` (three point handles) and pose it once: the rig, the
    build's seconds and the first frame's."""
    import jax

    import mvcjax

    shape = mvcjax.Shape.from_polygon(polygon)
    t0 = time.perf_counter()
    rig = mvcjax.Rig.build(shape, [tuple(p) for p in polygon[::2][:3] * 0.3],
                           shape_spacing=shape.diagonal / 60)
    t1 = time.perf_counter()
    jax.block_until_ready(rig.deform(rig.handle_positions + 0.02 * shape.diagonal))
    return rig, t1 - t0, time.perf_counter() - t1


def measure(count: int) -> tuple[list[dict], dict]:
    from mvcjax import _programs

    rng = np.random.default_rng(0)
    rows, new, same = [], [], []
    for i in range(count):
        points = int(rng.integers(5, 12))
        outer = float(rng.uniform(60, 120))
        polygon = star(points, outer, outer * float(rng.uniform(0.35, 0.6)))
        rig, build_s, frame_s = posed(polygon)
        new.append((build_s, frame_s))
        if i % 10 == 5:
            # The same star again: the same sizes, compiled just before.
            _, build_s, frame_s = posed(polygon.copy())
            same.append((build_s, frame_s))
        if i % 10 == 9 or i == count - 1:
            rows.append({"rigs": i + 1, "memory_maps": memory_maps(),
                         "resident_mb": resident_mb(),
                         "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                         "control_vertices": int(rig.control_mesh.vertices.shape[0])})
    warm = [r for r in rows if r["rigs"] > 2 * _programs.SIZES_KEPT] or rows
    summary = {
        "sizes_kept": _programs.SIZES_KEPT,
        "max_memory_maps_after_warmup": max(r["memory_maps"] for r in warm),
        "max_resident_mb_after_warmup": max(r["resident_mb"] for r in warm),
        "new_size_build_s": float(np.median([b for b, _ in new])),
        "new_size_first_frame_s": float(np.median([f for _, f in new])),
        "same_size_build_s": float(np.median([b for b, _ in same])),
        "same_size_first_frame_s": float(np.median([f for _, f in same])),
    }
    return rows, summary


def format_table(data: dict) -> str:
    s = data["meta"]["summary"]
    lines = ["| rigs built | memory maps | resident memory |", "|---|---|---|"]
    rows = data["rows"]
    # At most about 20 lines: every row of a short run, every few of a long one.
    every = max(1, len(rows) // 20)
    lines += [f"| {r['rigs']} | {r['memory_maps']} | {r['resident_mb']:.0f} MB |"
              for r in rows[every - 1::every]]
    lines += ["", f"After the warm-up (the first {2 * s['sizes_kept']} rigs): at most "
              f"{s['max_memory_maps_after_warmup']} memory maps and "
              f"{s['max_resident_mb_after_warmup']:.0f} MB resident."]
    lines += ["", "| a new rig | build | first frame |", "|---|---|---|",
              f"| of a new size | {s['new_size_build_s']:.2f} s | "
              f"{s['new_size_first_frame_s']:.2f} s |",
              f"| of a size already compiled | {s['same_size_build_s']:.2f} s | "
              f"{s['same_size_first_frame_s']:.3f} s |"]
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "30 rigs instead of 1,000", argv)
    count = 30 if args.quick else 1000
    start = time.perf_counter()
    rows, summary = measure(count)
    for row in rows:
        print(row, flush=True)
    print(summary)
    if args.json:
        write_results(args.json, rows, benchmark="many_rigs", quick=args.quick,
                      summary=summary, seconds=time.perf_counter() - start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
