"""Many characters in one call: a font's glyphs rigged, stacked (`Rig.stack`,
`Renderer.stack`), and posed and drawn by `jax.vmap` over characters and frames in one
compiled program, against a loop over the characters (each rig's own programs,
`jax.vmap` over its frames).

Glyphs of DejaVu Sans (letters, digits, Greek), each with four pins (the ends of its
bottom and top strokes), posed by a smooth random animation of `--frames` frames (the
pins swaying by up to 6% of the glyph's size), drawn at 128 x 128 with the checkerboard
fill. Both ways give the same pictures (checked: the largest difference is printed).
Compilation is timed apart: the stack compiles one program, the loop one per glyph
size. Runs are the median of `--repeats`.

    python benchmarks/stack.py [--quick] [--json benchmarks/results/stack-cpu-2core.json]
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from _timing import spacing_for, write_results

LETTERS = ("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghklmnopqrstuvwxyz0123456789"
           "ΑΒΓΔΕΖΗΘΚΛΜΝΞΟΠΡΣΤΥΦΧΨΩαβγδεζηθκλμνξπρστυφχψω")
SIZE = (128, 128)
# The stacks of similar sizes the glyphs are also posed in.
GROUPS = 4
# Frames posed and drawn per call of the stack's program: its pictures, as bytes, stay
# near 100 MB for 100 glyphs.
CHUNK = 16


def glyph_rigs(count: int, vertices: int):
    """`count` glyph rigs of about `vertices` shape vertices, four pins each."""
    import mvcjax
    from mvcjax.datasets import glyph_handles
    from mvcjax.generate import glyph_sprites

    rigs = []
    for shape in glyph_sprites(LETTERS, size=96).values():
        rows = glyph_handles(shape)
        if len(rows[0]) < 2 or len(rows[-1]) < 2:
            continue
        pins = np.array([rows[0][0], rows[0][-1], rows[-1][0], rows[-1][-1]])
        rigs.append(mvcjax.Rig.build(shape, pins,
                                     shape_spacing=spacing_for(shape, vertices)))
        if len(rigs) == count:
            break
    return rigs


def animation(rigs, frames: int, seed: int = 0) -> np.ndarray:
    """`(glyphs, frames, 4, 2)` targets: each pin swaying smoothly about its rest."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / frames * 2 * np.pi
    out = []
    for rig in rigs:
        rest = np.asarray(rig.handle_positions, np.float64)
        size = float(rig.frame.scale)
        amplitude = rng.uniform(-0.06, 0.06, (1, *rest.shape)) * size
        phase = rng.uniform(0, 2 * np.pi, (1, *rest.shape))
        out.append(rest + amplitude * np.sin(t[:, None, None] + phase))
    return np.asarray(out, np.float32)


def _bytes(pictures):
    import jax.numpy as jnp

    return jnp.round(jnp.clip(pictures, 0.0, 1.0) * 255).astype(jnp.uint8)


def measure(count: int, frames: int, vertices: int, repeats: int) -> dict:
    import jax

    import mvcjax

    t0 = time.perf_counter()
    rigs = glyph_rigs(count, vertices)
    build_s = time.perf_counter() - t0
    targets = animation(rigs, frames)
    sizes = [int(r.shape_mesh.vertices.shape[0]) for r in rigs]

    t0 = time.perf_counter()
    stack = mvcjax.Rig.stack(rigs)
    stack_s = time.perf_counter() - t0
    pose = jax.jit(jax.vmap(jax.vmap(lambda r, t: r.deform(t), in_axes=(None, 0))))
    poses = np.asarray(pose(stack, targets))
    windows = [mvcjax.fit_window(poses[i, :, :n].reshape(-1, 2), SIZE)
               for i, n in enumerate(sizes)]
    t0 = time.perf_counter()
    renderers = [mvcjax.Renderer.build(r, size=SIZE, window=w) for r, w in zip(rigs, windows)]
    renderers_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    drawn = mvcjax.Renderer.stack(renderers)
    stack_s += time.perf_counter() - t0

    @jax.jit
    def stack_chunk(rig, renderer, targets):
        vertices = jax.vmap(jax.vmap(lambda r, t: r.deform(t), in_axes=(None, 0)))(rig, targets)
        return _bytes(jax.vmap(lambda r, v: jax.vmap(r)(v))(renderer, vertices))

    @jax.jit
    def loop_chunk(rig, renderer, targets):
        return _bytes(jax.vmap(lambda t: renderer(rig.deform(t)))(targets))

    chunks = [targets[:, f:f + CHUNK] for f in range(0, frames, CHUNK)]

    def run_stack():
        return np.concatenate([np.asarray(stack_chunk(stack, drawn, c)) for c in chunks],
                              axis=1)

    # The glyphs in GROUPS stacks of similar sizes (sorted by shape vertices): less
    # padding, a program per group.
    order = np.argsort(sizes, kind="stable")
    groups = [g for g in np.array_split(order, min(GROUPS, len(rigs))) if len(g)]
    t0 = time.perf_counter()
    grouped = [(g, mvcjax.Rig.stack([rigs[i] for i in g]),
                mvcjax.Renderer.stack([renderers[i] for i in g])) for g in groups]
    groups_s = time.perf_counter() - t0

    def run_groups():
        out = np.empty((len(rigs), frames, *SIZE, 4), np.uint8)
        for g, rig, renderer in grouped:
            out[g] = np.concatenate([np.asarray(stack_chunk(rig, renderer, c[g]))
                                     for c in chunks], axis=1)
        return out

    def run_loop():
        return np.stack([np.concatenate([np.asarray(loop_chunk(r, d, c[i]))
                                         for c in chunks]) for i, (r, d)
                         in enumerate(zip(rigs, renderers))])

    def timed(fn):
        t0 = time.perf_counter()
        out = fn()
        return out, time.perf_counter() - t0

    stack_pictures, stack_first_s = timed(run_stack)  # compiles once
    stack_runs = [timed(run_stack)[1] for _ in range(repeats)]
    group_pictures, groups_first_s = timed(run_groups)  # compiles once per group
    groups_runs = [timed(run_groups)[1] for _ in range(repeats)]
    groups_s_run = float(np.median(groups_runs))
    # The loop's programs, one per glyph size, each hold memory maps: the others' go
    # first, or a hundred sizes reach the kernel's limit on maps.
    jax.clear_caches()
    loop_pictures, loop_first_s = timed(run_loop)  # compiles once per glyph size
    loop_runs = [timed(run_loop)[1] for _ in range(repeats)]
    stack_s_run, loop_s_run = float(np.median(stack_runs)), float(np.median(loop_runs))
    pictures = len(rigs) * frames
    difference = np.abs(stack_pictures.astype(int) - loop_pictures.astype(int)).max(axis=-1)
    return {
        "glyphs": len(rigs), "frames": frames, "size": list(SIZE),
        "shape_vertices_min": min(sizes), "shape_vertices_max": max(sizes),
        "distinct_sizes": len(set(sizes)),
        "build_s": build_s, "renderers_build_s": renderers_s, "stack_s": stack_s,
        "stack_compile_s": stack_first_s - stack_s_run,
        "loop_compile_s": loop_first_s - loop_s_run,
        "stack_run_s": stack_s_run, "loop_run_s": loop_s_run,
        "stack_pictures_per_s": pictures / stack_s_run,
        "loop_pictures_per_s": pictures / loop_s_run,
        "speedup": loop_s_run / stack_s_run,
        "groups": len(grouped), "groups_stack_s": groups_s,
        "groups_compile_s": groups_first_s - groups_s_run, "groups_run_s": groups_s_run,
        "groups_pictures_per_s": pictures / groups_s_run,
        "groups_speedup": loop_s_run / groups_s_run,
        "groups_pixels_differing_share": float(np.mean(np.abs(
            group_pictures.astype(int) - loop_pictures.astype(int)).max(axis=-1) > 2)),
        # The poses agree to float32 rounding; a pixel on an edge can still fall to
        # another triangle.
        "max_byte_difference": int(difference.max()),
        "pixels_differing_share": float(np.mean(difference > 2)),
        "repeats": repeats,
    }


def format_table(data: dict) -> str:
    r = data["rows"][0]
    lines = [
        f"{r['glyphs']} glyphs ({r['shape_vertices_min']:,} to {r['shape_vertices_max']:,} "
        f"shape vertices, {r['distinct_sizes']} sizes) x {r['frames']} frames, posed and "
        f"drawn at {r['size'][0]} x {r['size'][1]}:", "",
        "| | pictures a second | run | compile |", "|---|---|---|---|",
        f"| stack (`Rig.stack`, `Renderer.stack`, one program) | "
        f"{r['stack_pictures_per_s']:.0f} | {r['stack_run_s']:.2f} s | "
        f"{r['stack_compile_s']:.1f} s |",
        f"| {r['groups']} stacks of glyphs of similar sizes (a program each) | "
        f"{r['groups_pictures_per_s']:.0f} | {r['groups_run_s']:.2f} s | "
        f"{r['groups_compile_s']:.1f} s |",
        f"| loop over the glyphs (a program per size) | {r['loop_pictures_per_s']:.0f} | "
        f"{r['loop_run_s']:.2f} s | {r['loop_compile_s']:.1f} s |",
        "",
        f"Once compiled, the stack runs {r['speedup']:.2f} times as fast as the loop, "
        f"the {r['groups']} stacks {r['groups_speedup']:.2f} times: every glyph does the "
        "work of the largest of its stack, and on a CPU each glyph's frames are already "
        "one batched product in the loop. From a cold start, compiling "
        f"included, the stack takes {r['stack_compile_s'] + r['stack_run_s']:.0f} s and "
        f"the loop {r['loop_compile_s'] + r['loop_run_s']:.0f} s. Stacking took "
        f"{r['stack_s']:.1f} s (building the rigs {r['build_s']:.0f} s, their renderers "
        f"{r['renderers_build_s']:.0f} s). The pictures agree within 2 in 255 but for "
        f"{100 * r['pixels_differing_share']:.4f}% of the pixels (edge pixels that fall to "
        "another triangle, the poses agreeing to float32 rounding).",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 glyphs x 8 frames")
    parser.add_argument("--glyphs", type=int, default=100)
    parser.add_argument("--frames", type=int, default=64)
    parser.add_argument("--vertices", type=int, default=1500,
                        help="about how many shape vertices a glyph's mesh has")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="write the results to this JSON file")
    args = parser.parse_args(argv)
    glyphs, frames = (3, 8) if args.quick else (args.glyphs, args.frames)
    start = time.perf_counter()
    row = measure(glyphs, frames, args.vertices, 1 if args.quick else args.repeats)
    print(row)
    data = {"rows": [row]}
    print(format_table(data))
    if args.json:
        write_results(args.json, [row], benchmark="stack", quick=args.quick,
                      seconds=time.perf_counter() - start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
