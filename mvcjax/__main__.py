"""Command line: `mvcjax demo [--out FILE.png] [--animation FILE.gif]`."""

from __future__ import annotations

import argparse
import sys
import time


def _say(message: str) -> None:
    print(message, flush=True)


def _demo(args) -> int:
    import jax
    import numpy as np

    import mvcjax
    from mvcjax import datasets, export

    _say("mvcjax demo: the built-in horse, dragged by its handles")
    _say("  meshing the horse and building its rig ...")
    t0 = time.perf_counter()
    shape = datasets.horse()
    rig = mvcjax.Rig.build(shape, datasets.horse_handles(), shape_spacing=args.shape_spacing)
    jax.block_until_ready(rig)
    build = time.perf_counter() - t0

    # A drag there and back, eased, as an animation's frames.
    rest = np.asarray(rig.handle_positions)
    ease = 0.5 - 0.5 * np.cos(np.linspace(0.0, 2.0 * np.pi, args.frames, endpoint=False))
    targets = rest[None] + ease[:, None, None] * np.asarray(datasets.horse_drag())[None]
    deform = jax.jit(rig.deform)  # the fastest compiled frame: the rig's arrays as constants
    _say("  compiling the solve and the skinning ...")
    t0 = time.perf_counter()
    deform(targets[args.frames // 2]).block_until_ready()
    compile_time = time.perf_counter() - t0
    times = []
    for frame in targets[:: max(1, args.frames // 8)].tolist() * 10:
        t0 = time.perf_counter()
        deform(np.asarray(frame)).block_until_ready()
        times.append(time.perf_counter() - t0)
    frame_time = float(np.median(times))

    _say(f"  deforming {args.frames} frames and drawing them textured ...")
    t0 = time.perf_counter()
    frames = mvcjax.deform_frames(rig, targets)
    window = mvcjax.fit_window(np.concatenate([np.asarray(frames),
                                               np.asarray(rig.shape_mesh.vertices)[None]]),
                               (args.size, args.size), margin=0.03)
    renderer = mvcjax.Renderer.build(rig, size=(args.size, args.size), window=window)
    pictures = renderer.frames(frames)
    draw_time = time.perf_counter() - t0
    export.write_animation(args.animation, pictures, fps=24)

    _say("  drawing the figure ...")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mvcjax import plot

    posed = pictures[args.frames // 2]
    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5.5))
    plot.plot_rig(rig, a)
    a.set_title("rest: shape mesh (grey) under control mesh (blue)")
    xmin, ymin, xmax, ymax = window
    plot.plot_outline(rig, b, color="0.35", linewidth=1.0, linestyle="--", zorder=1)
    b.imshow(posed, extent=(xmin, xmax, ymin, ymax), interpolation="bilinear", zorder=2)
    b.plot(*targets[args.frames // 2].T, "x", color="k", markersize=7, zorder=3)
    b.set_xlim(xmin, xmax)
    b.set_ylim(ymin, ymax)
    b.set_aspect("equal")
    b.set_xticks([])
    b.set_yticks([])
    b.set_title("deformed (checkerboard texture) over the rest outline (dashed); x: targets")
    fig.tight_layout()
    fig.savefig(args.out, dpi=args.dpi)
    plt.close(fig)

    cm = rig.control_mesh
    _say(f"shape      : {shape}")
    _say(f"shape mesh : {rig.shape_mesh.vertices.shape[0]} vertices, "
         f"{rig.shape_mesh.faces.shape[0]} triangles")
    _say(f"control    : {cm.vertices.shape[0]} vertices ({cm.outer.shape[0]} on the polygon, "
         f"{cm.inner.shape[0]} inner), {cm.faces.shape[0]} triangles, "
         f"{cm.handles.shape[0]} handles")
    _say(f"dtype      : {rig.energy.rest.dtype}, device {jax.devices()[0].platform}")
    _say(f"preprocess : {build * 1e3:.0f} ms (meshing, skinning weights, G)")
    _say(f"compile    : {compile_time * 1e3:.0f} ms (solve + skin, once)")
    _say(f"per frame  : {frame_time * 1e3:.3f} ms (FixedG, 15 iterations, + blended MVC "
         f"skinning; median of {len(times)})")
    _say(f"animation  : {args.animation} ({args.frames} frames, {args.size}x{args.size}; "
         f"deformed and drawn in {draw_time:.1f} s, compiling included)")
    _say(f"figure     : {args.out}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="mvcjax", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="deform the built-in horse and write a figure")
    demo.add_argument("--out", default="mvcjax-demo.png", help="PNG figure to write")
    demo.add_argument("--animation", default="mvcjax-demo.gif",
                      help="animation to write (.gif, .png, .webp or .mp4)")
    demo.add_argument("--frames", type=int, default=48, help="frames in the animation")
    demo.add_argument("--size", type=int, default=320, help="animation side, in pixels")
    demo.add_argument("--shape-spacing", type=float, default=None,
                      help="edge length of the shape mesh (default: the rig's)")
    demo.add_argument("--dpi", type=int, default=110)
    args = parser.parse_args(argv)
    if args.command == "demo":
        return _demo(args)
    return 2


if __name__ == "__main__":
    sys.exit(main())
