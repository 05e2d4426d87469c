"""Many rigs of different sizes in one process: memory maps and resident memory as the
rigs go by, and the time of a new rig's build and first frame, for a size whose
programs are compiled and for a new one; rigs built plain and with a `SizeLadder`.

Stars of 5 to 11 points and random radii, meshed at a sixtieth of their diagonal (about
1,000 to 1,800 shape vertices), each built and posed once (`rig.deform`), one after
another, as a script that rigs every glyph of a font does. A rig's programs go with the
last rig of its size (`mvcjax.core._programs` says why and how); the maps and the
resident memory are read from `/proc/self` every 10 rigs, over 1,000 rigs.
Each way runs in a fresh process of its own, the same stars in the same order.

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


# Rigs counted as the warm-up: the memory reported is the most after them.
WARM_UP = 32


def size_of(tree) -> tuple:
    """What decides the programs compiled for `tree`: its structure and its arrays'
    shapes and dtypes."""
    import jax

    leaves, structure = jax.tree.flatten(tree)
    return structure, tuple((np.shape(x), str(np.result_type(x))) for x in leaves)


def memory_maps() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


def resident_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20


def posed(polygon: np.ndarray, ladder=None):
    """Build a rig of `polygon` (three point handles) and pose it once: the rig, the
    build's seconds and the first frame's."""
    import jax

    import mvcjax

    shape = mvcjax.Shape.from_polygon(polygon)
    t0 = time.perf_counter()
    rig = mvcjax.Rig.build(shape, [tuple(p) for p in polygon[::2][:3] * 0.3],
                           shape_spacing=shape.diagonal / 60, ladder=ladder)
    t1 = time.perf_counter()
    jax.block_until_ready(rig.deform(rig.handle_positions + 0.02 * shape.diagonal))
    return rig, t1 - t0, time.perf_counter() - t1


def measure(count: int, laddered: bool) -> tuple[list[dict], dict]:
    """`count` stars built and posed one after another, plain or with a `SizeLadder`:
    rows of memory as they go by, and a summary of the times."""
    import mvcjax
    from mvcjax.rig._ladder import padded_twin

    ladder = mvcjax.SizeLadder() if laddered else None
    rng = np.random.default_rng(0)
    rows, new, same, sizes, rungs = [], [], [], set(), set()
    for i in range(count):
        points = int(rng.integers(5, 12))
        outer = float(rng.uniform(60, 120))
        polygon = star(points, outer, outer * float(rng.uniform(0.35, 0.6)))
        rig, build_s, frame_s = posed(polygon, ladder)
        sizes.add(size_of(rig))
        if padded_twin(rig) is not None:
            rungs.add(size_of(padded_twin(rig)))
        new.append((build_s, frame_s))
        if i % 10 == 5:
            # The same star again: the same sizes, compiled just before.
            _, build_s, frame_s = posed(polygon.copy(), ladder)
            same.append((build_s, frame_s))
        if i % 10 == 9 or i == count - 1:
            rows.append({"rigs": i + 1, "memory_maps": memory_maps(),
                         "resident_mb": resident_mb(),
                         "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
                         "control_vertices": int(rig.control_mesh.vertices.shape[0])})
    warm = [r for r in rows if r["rigs"] > WARM_UP] or rows
    totals = [b + f for b, f in new]
    summary = {
        "ladder": laddered,
        "warm_up": WARM_UP,
        "rig_sizes": len(sizes),
        "twin_sizes": len(rungs),
        "max_memory_maps_after_warmup": max(r["memory_maps"] for r in warm),
        "max_resident_mb_after_warmup": max(r["resident_mb"] for r in warm),
        "new_size_build_s": float(np.median([b for b, _ in new])),
        "new_size_first_frame_s": float(np.median([f for _, f in new])),
        "new_rig_total_s": float(np.median(totals)),
        "new_rig_total_mean_s": float(np.mean(totals)),
        "same_size_build_s": float(np.median([b for b, _ in same])),
        "same_size_first_frame_s": float(np.median([f for _, f in same])),
    }
    return rows, summary


def measure_both(count: int) -> dict:
    """Both ways, each in a fresh process (their compiled programs apart)."""
    import multiprocessing

    out = {}
    for name, laddered in (("plain", False), ("ladder", True)):
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            out[name] = pool.apply(measure, (count, laddered))
    return out


def format_table(data: dict) -> str:
    summary = data["meta"]["summary"]
    ways = [w for w in ("plain", "ladder") if w in summary]
    by_way = {w: [r for r in data["rows"] if r["way"] == w] for w in ways}
    names = {"plain": "plain", "ladder": "`ladder=SizeLadder()`"}
    lead = {"plain": "Plain", "ladder": "With `ladder=SizeLadder()`"}
    lines = ["| rigs built | " + " | ".join(f"memory maps, {names[w]} | resident, {names[w]}"
                                           for w in ways) + " |",
             "|---|" + "---|---|" * len(ways)]
    first = by_way[ways[0]]
    # At most about 20 lines: every row of a short run, every few of a long one.
    every = max(1, len(first) // 20)
    for k in range(every - 1, len(first), every):
        cells = [f"{by_way[w][k]['memory_maps']} | {by_way[w][k]['resident_mb']:.0f} MB"
                 for w in ways]
        lines.append(f"| {first[k]['rigs']} | " + " | ".join(cells) + " |")
    lines.append("")
    for w in ways:
        s = summary[w]
        lines.append(f"- {lead[w]}: after the warm-up (the first "
                     f"{s.get('warm_up', 2 * s.get('sizes_kept', 16))} rigs), at most "
                     f"{s['max_memory_maps_after_warmup']} memory maps and "
                     f"{s['max_resident_mb_after_warmup']:.0f} MB resident; "
                     f"{s['rig_sizes']} rig sizes"
                     + (f", {s['twin_sizes']} twin sizes" if s["ladder"] else "") + ".")
    lines += ["", "| a new rig | " + " | ".join(names[w] for w in ways) + " |",
              "|---|" + "---|" * len(ways)]
    rows = [("build, a new star (median)", "new_size_build_s", "{:.2f} s"),
            ("first frame, a new star (median)", "new_size_first_frame_s", "{:.3f} s"),
            ("build and first frame, a new star (mean)", "new_rig_total_mean_s",
             "{:.2f} s"),
            ("build, the same star again", "same_size_build_s", "{:.2f} s"),
            ("first frame, the same star again", "same_size_first_frame_s", "{:.3f} s")]
    for label, key, fmt in rows:
        lines.append(f"| {label} | " + " | ".join(fmt.format(summary[w][key]) for w in ways)
                     + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = quick_and_json(__doc__, "12 rigs instead of 1,000", argv)
    count = 12 if args.quick else 1000
    start = time.perf_counter()
    both = measure_both(count)
    rows = [{"way": way, **row} for way, (way_rows, _) in both.items() for row in way_rows]
    summary = {way: s for way, (_, s) in both.items()}
    for row in rows:
        print(row, flush=True)
    print(summary)
    if args.json:
        write_results(args.json, rows, benchmark="many_rigs", quick=args.quick,
                      summary=summary, seconds=time.perf_counter() - start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
