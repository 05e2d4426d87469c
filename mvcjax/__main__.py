"""Command line: `mvcjax demo [--out FILE.png]`."""

from __future__ import annotations

import argparse
import sys
import time


def _demo(args) -> int:
    import jax
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    t0 = time.perf_counter()
    shape = datasets.horse()
    handles = datasets.horse_handles()
    rig = mvcjax.Rig.build(shape, handles, shape_spacing=args.shape_spacing)
    jax.block_until_ready(rig)
    build = time.perf_counter() - t0

    rest = np.asarray(rig.handle_positions)
    frames = [rest + s * datasets.horse_drag() for s in np.linspace(0.0, 1.0, 8)]
    deform = jax.jit(lambda r, t: r.deform(t))
    t0 = time.perf_counter()
    shape_vertices = deform(rig, frames[-1]).block_until_ready()
    compile_time = time.perf_counter() - t0
    times = []
    for targets in frames * 10:
        t0 = time.perf_counter()
        deform(rig, targets).block_until_ready()
        times.append(time.perf_counter() - t0)
    frame = float(np.median(times))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mvcjax import plot

    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5.5))
    plot.plot_rig(rig, a)
    a.set_title("rest: shape mesh (grey) under control mesh (blue)")
    control = rig.solve(frames[-1])
    plot.plot_rig(rig, b, control_vertices=control, shape_vertices=shape_vertices,
                  targets=frames[-1])
    b.set_title("deformed: handles (red) dragged to targets (x)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=args.dpi)
    plt.close(fig)

    cm = rig.control_mesh
    print(f"shape      : {shape}")
    print(f"shape mesh : {rig.shape_mesh.vertices.shape[0]} vertices, "
          f"{rig.shape_mesh.faces.shape[0]} triangles")
    print(f"control    : {cm.vertices.shape[0]} vertices ({cm.outer.shape[0]} on the polygon, "
          f"{cm.inner.shape[0]} inner), {cm.faces.shape[0]} triangles, "
          f"{cm.handles.shape[0]} handles")
    print(f"dtype      : {rig.energy.rest.dtype}, device {jax.devices()[0].platform}")
    print(f"preprocess : {build * 1e3:.0f} ms (meshing, skinning weights, G)")
    print(f"compile    : {compile_time * 1e3:.0f} ms (solve + skin, once)")
    print(f"per frame  : {frame * 1e3:.3f} ms (FixedG, 15 iterations, + blended MVC skinning; "
          f"median of {len(times)})")
    print(f"figure     : {args.out}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="mvcjax", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="deform the built-in horse and write a figure")
    demo.add_argument("--out", default="mvcjax-demo.png", help="PNG file to write")
    demo.add_argument("--shape-spacing", type=float, default=None,
                      help="edge length of the shape mesh (default: the rig's)")
    demo.add_argument("--dpi", type=int, default=110)
    args = parser.parse_args(argv)
    if args.command == "demo":
        return _demo(args)
    return 2


if __name__ == "__main__":
    sys.exit(main())
