"""Command line: `mvcjax demo [--out FILE.png] [--animation FILE.gif] [--layers FILE.gif]`,
`mvcjax dataset SPRITES OUT [--poses N] [--size PIXELS] ...` and
`mvcjax animate SCENE.yaml OUT.gif` (AnimatedDrawings' files)."""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time

import lazy_loader
import numpy as np
import platformdirs

import mvcjax

# Loaded on first use, so that `--help` and a refused command answer without JAX.
jax = lazy_loader.load("jax")
plot = lazy_loader.load("mvcjax.plot", suppress_warning=True)
solvers = lazy_loader.load("mvcjax.solvers", suppress_warning=True)


# mvcjax.generate.PoseLimits' numbers, each an option of `mvcjax dataset`.
LIMITS = {
    "offset": "the largest distance a handle moves, a fraction of the shape's size",
    "spread": "the distance over which handles move alike, a fraction of the shape's size",
    "turn": "the largest turn of the whole pose, in degrees either way",
    "bone_turn": "the largest turn of a bone about its start, in degrees either way",
}
PROGRESS = ("a progress bar on standard error (default: on for a long run on a terminal, "
            "off otherwise)")


# JAX's persistent compilation cache, as `jax.config` names its settings: every program,
# however quick to compile (a command compiles many small ones).
CACHE_SETTINGS = {"jax_persistent_cache_min_compile_time_secs": 0.0,
                  "jax_persistent_cache_min_entry_size_bytes": 0}


def _keep_compiled(folder: str | None) -> None:
    """Keep what the command compiles in JAX's persistent compilation cache in `folder`
    (`--compile-cache`; None: $MVCJAX_COMPILE_CACHE, else the user's cache folder;
    "off": none), so that the next run loads it instead of compiling. Where the user
    set JAX's own cache folder (`JAX_COMPILATION_CACHE_DIR`), that one is used."""
    folder = folder or os.environ.get("MVCJAX_COMPILE_CACHE") or _default_cache()
    if folder == "off" or os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return
    settings = {"jax_compilation_cache_dir": folder, **CACHE_SETTINGS}
    if "jaxlib" in sys.modules:  # JAX loaded: main() called from Python (`jax` is lazy)
        for name, value in settings.items():
            jax.config.update(name, value)
    else:  # read when JAX loads, after the command has checked its input
        os.environ.update({name.upper(): str(value) for name, value in settings.items()})


def _default_cache() -> str:
    return os.path.join(platformdirs.user_cache_dir("mvcjax"), "jax")


def _say(message: str) -> None:
    print(message, flush=True)


def _demo(args) -> int:
    _say("mvcjax demo: the built-in horse, dragged by its handles")
    _say("  meshing the horse and building its rig ...")
    t0 = time.perf_counter()
    shape = mvcjax.datasets.horse()
    rig = mvcjax.Rig.build(shape, mvcjax.datasets.horse_handles(),
                           shape_spacing=args.shape_spacing)
    jax.block_until_ready(rig)
    build = time.perf_counter() - t0
    targets = _horse_drag(rig, args.frames)
    compile_time, times = _time_deform(rig, targets, args.frames)

    _say(f"  deforming {args.frames} frames and drawing them textured ...")
    t0 = time.perf_counter()
    pictures, window = _draw_frames(rig, targets, args.size)
    draw_time = time.perf_counter() - t0
    mvcjax.export.write_animation(args.animation, pictures, fps=24)

    _say("  raising the character's arm overhead, plainly and with FoldFree ...")
    arm = _arm_overhead(args.arm_degrees)

    _say("  drawing the figure ...")
    _draw_figure(args, rig, pictures[args.frames // 2], targets[args.frames // 2], window, arm)

    _say_rig(shape, rig)
    _say(f"preprocess : {build * 1e3:.0f} ms (meshing, skinning weights, G)")
    _say(f"compile    : {compile_time * 1e3:.0f} ms (solve + skin, once)")
    iterations = solvers.DEFAULT_SOLVER.iterations
    _say(f"per frame  : {float(np.median(times)) * 1e3:.3f} ms (rig.deform's default: "
         f"FixedG, {iterations} iterations from the turned start, + blended MVC skinning; "
         f"median of {len(times)})")
    for name, (_, info, folded) in arm["poses"].items():
        _say(f"arm        : {name:<9}: {folded} shape triangles folded, "
             f"{int(info.inverted)} control triangles inverted, handles missed by "
             f"{float(info.handle_miss):.2f}")
    # A frame the same as the one before is written as one image held longer.
    images = 1 + int(np.any(pictures[1:] != pictures[:-1], axis=(1, 2, 3)).sum())
    held = "" if images == args.frames else f" in {images} images, a repeated frame held"
    _say(f"animation  : {args.animation} ({args.frames} frames{held}, "
         f"{args.size}x{args.size}; deformed and drawn in {draw_time:.1f} s, compiling "
         "included)")
    _say(f"figure     : {args.out}")
    if args.layers is not None:
        _layers_demo(args.layers, args.frames)
    return 0


def _horse_drag(rig, frames: int) -> np.ndarray:
    """The horse's handle targets `(frames, t, 2)` of a drag there and back, eased, as an
    animation's frames."""
    rest = np.asarray(rig.handle_positions)
    ease = 0.5 - 0.5 * np.cos(np.linspace(0.0, 2.0 * np.pi, frames, endpoint=False))
    return rest[None] + ease[:, None, None] * np.asarray(mvcjax.datasets.horse_drag())[None]


def _time_deform(rig, targets: np.ndarray, frames: int) -> tuple[float, list[float]]:
    """Seconds to compile `rig.deform`, and seconds of each of its compiled calls on
    some of the `targets`, ten times over."""
    deform = jax.jit(rig.deform)  # the fastest compiled frame: the rig's arrays as constants
    _say("  compiling the solve and the skinning ...")
    t0 = time.perf_counter()
    deform(targets[frames // 2]).block_until_ready()
    compile_time = time.perf_counter() - t0
    times = []
    for frame in targets[:: max(1, frames // 8)].tolist() * 10:
        t0 = time.perf_counter()
        deform(np.asarray(frame)).block_until_ready()
        times.append(time.perf_counter() - t0)
    return compile_time, times


def _draw_frames(rig, targets: np.ndarray, size: int) -> tuple:
    """The rig deformed to each of `targets` and drawn textured, `size` pixels square,
    in a window that holds every frame and the rest shape: the pictures and the window."""
    frames = mvcjax.deform_frames(rig, targets)
    window = mvcjax.fit_window(np.concatenate([np.asarray(frames),
                                               np.asarray(rig.shape_mesh.vertices)[None]]),
                               (size, size), margin=0.03)
    renderer = mvcjax.Renderer.build(rig, size=(size, size), window=window)
    return renderer.frames(frames), window


def _draw_figure(args, rig, posed, posed_targets, window, arm: dict) -> None:
    """The demo's figure, written to `args.out`: the rest rig, the horse posed, and the
    arm turned by the default solver and by `FoldFree`."""
    import matplotlib  # lazily: only the demo's figure needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ((a, b), (c, d)) = plt.subplots(2, 2, figsize=(13, 11),
                                         gridspec_kw={"height_ratios": [1.0, 1.1]})
    plot.plot_rig(rig, a)
    a.set_title("rest: shape mesh (grey) under control mesh (blue)")
    _plot_posed(b, rig, posed, posed_targets, window)
    _plot_arm_poses((c, d), arm, args.arm_degrees)
    fig.tight_layout()
    fig.savefig(args.out, dpi=args.dpi)
    plt.close(fig)


def _plot_posed(ax, rig, posed, posed_targets, window) -> None:
    """The posed picture over the rest outline (dashed), its targets marked x."""
    xmin, ymin, xmax, ymax = window
    plot.plot_outline(rig, ax, color="0.35", linewidth=1.0, linestyle="--", zorder=1)
    ax.imshow(posed, extent=(xmin, xmax, ymin, ymax), interpolation="bilinear", zorder=2)
    ax.plot(*posed_targets.T, "x", color="k", markersize=7, zorder=3)
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title("deformed (checkerboard texture) over the rest outline (dashed); x: targets")


def _plot_arm_poses(axes, arm: dict, degrees: float) -> None:
    """Each pose of `_arm_overhead` on its own axes, its folds in red, all framed alike."""
    arm_rig, arm_targets = arm["rig"], arm["targets"]
    for ax, (name, (vertices, _, folded)) in zip(axes, arm["poses"].items()):
        plot.plot_outline(arm_rig, ax, color="0.6", linewidth=0.8, linestyle="--")
        plot.plot_mesh(vertices, arm_rig.shape_mesh.faces, ax, color="tab:green", linewidth=0.25)
        plot.plot_folds(arm_rig, vertices, ax)
        ax.plot(*np.asarray(arm_targets).T, "x", color="k", markersize=7)
        ax.set_title(f"right arm turned {degrees:g} degrees: {name}, "
                     f"{folded} triangles folded (red)", fontsize=10)
    # Framed to hold every pose and the rest outline drawn under them.
    points = np.concatenate([np.asarray(arm_rig.shape_mesh.vertices),
                             *(np.asarray(v) for v, _, _ in arm["poses"].values())])
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = 0.04 * (hi - lo).max()
    for ax in axes:
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)


def _say_rig(shape, rig) -> None:
    """Print the shape, the sizes of the rig's meshes, and its dtype and device."""
    cm = rig.control_mesh
    _say(f"shape      : {shape}")
    _say(f"shape mesh : {rig.shape_mesh.vertices.shape[0]} vertices, "
         f"{rig.shape_mesh.faces.shape[0]} triangles")
    _say(f"control    : {cm.vertices.shape[0]} vertices ({cm.outer.shape[0]} on the polygon, "
         f"{cm.inner.shape[0]} inner), {cm.faces.shape[0]} triangles, "
         f"{cm.handles.shape[0]} handles")
    _say(f"dtype      : {rig.energy.rest.dtype}, device {jax.devices()[0].platform}")


def _layers_demo(path, frames: int) -> None:
    """The built-in figure drawn in layers (a body, two arms over its sides, a hand of its
    own), its right arm swung across the body and back, written as an animation."""
    _say("  posing a character drawn in layers, its arm across the body and back ...")
    t0 = time.perf_counter()
    layers = mvcjax.datasets.layered_figure()
    character = mvcjax.Character.build(layers, mvcjax.datasets.layered_figure_handles())
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    parts = mvcjax.deform_frames(character, mvcjax.datasets.layered_figure_wave(frames))
    renderer = mvcjax.Renderer.build(character, layers, background=(1.0, 1.0, 1.0, 1.0))
    mvcjax.export.write_animation(path, renderer.frames(parts), fps=24)
    _say(f"layers     : {character}")
    _say(f"           : built in {build:.1f} s; {frames} frames posed and drawn in "
         f"{time.perf_counter() - t0:.1f} s, compiling included: {path}")


def _arm_overhead(degrees: float) -> dict:
    """The built-in character with a bone per arm, its right arm turned `degrees` about
    the shoulder: the pose of the default solver and of `FoldFree`, each with its info
    and the number of folded shape triangles."""
    rig = mvcjax.Rig.build(mvcjax.datasets.character(), mvcjax.datasets.character_bones("arms"))
    targets = np.array(rig.handle_positions)
    # Rows 4 and 5: the right arm's bone, from the shoulder to the wrist.
    targets[5] = mvcjax.datasets._rotate(targets[5], targets[4], float(degrees))
    poses = {}
    for name, solver in (("default", solvers.DEFAULT_SOLVER),
                         ("FoldFree", mvcjax.FoldFree())):
        vertices, info = rig.deform(targets, solver, return_info=True)
        folded = mvcjax.flipped_triangles(rig.shape_mesh.vertices, vertices,
                                          rig.shape_mesh.faces)
        poses[name] = (vertices, info, folded)
    return {"rig": rig, "targets": targets, "poses": poses}


def _dataset(args) -> int:
    if args.coordinator is not None:
        jax.distributed.initialize(coordinator_address=args.coordinator,
                                   num_processes=args.num_processes,
                                   process_id=args.process_id)
    if args.glyphs is not None:
        sprites = mvcjax.generate.glyph_sprites(args.glyphs, font=args.font, size=args.glyph_size)
    else:
        sprites = args.sprites
    given = {name: getattr(args, name) for name in LIMITS if getattr(args, name) is not None}
    limits = mvcjax.generate.PoseLimits(**given, folds=args.folds)
    count = len(sprites) if isinstance(sprites, dict) else "the"
    _say(f"mvcjax dataset: {count} sprites of {args.sprites}, {args.poses} poses each, "
         f"{args.size}x{args.size} pixels, into {args.out} (process "
         f"{jax.process_index() + 1} of {jax.process_count()}, "
         f"{len(jax.local_devices())} local devices)")
    report = mvcjax.generate.write_dataset(
        sprites, args.out, poses=args.poses, size=args.size, limits=limits, seed=args.seed,
        batch=args.batch, progress=None if args.progress is None else args.progress == "on")
    _say(f"  {report.written} pictures written, {report.resumed} already there, "
         f"{len(report.skipped)} sprites skipped, in {report.seconds:.1f} s "
         f"({report.images_per_second:.1f} pictures a second)")
    for name, reason in report.skipped.items():
        _say(f"  skipped {name}: {reason}")
    return 0


def _animate_files_problem(files: list[str]) -> str | None:
    """What is wrong with `mvcjax animate`'s files, before anything is read or rigged
    (None where nothing is)."""
    if len(files) not in (2, 4):
        return ("give SCENE.yaml OUT, or CHARACTER MOTION.yaml RETARGET.yaml OUT "
                "(AnimatedDrawings' files).")
    *inputs, out = map(pathlib.Path, files)
    for k, path in enumerate(inputs):
        what = ("a scene .yaml" if len(inputs) == 1 else
                "a character folder or its char_cfg.yaml" if k == 0 else
                ("a motion" if k == 1 else "a retarget") + " config .yaml")
        if not path.exists():
            return f"{path}: no such file or folder; give {what}."
        if not (k == 0 and len(inputs) == 3 and path.is_dir()) and \
                path.suffix.lower() not in (".yaml", ".yml"):
            return f"{path}: not {what}; give {what} here."
    if out.suffix and out.suffix.lower() not in mvcjax.export.ANIMATION_SUFFIXES:
        return (f"{out}: mvcjax cannot write {out.suffix!r} animations; give a path ending "
                f"in {', '.join(mvcjax.export.ANIMATION_SUFFIXES)}, or one without a suffix "
                "for a folder of PNG frames.")
    return None


def _animate(args) -> int:
    files = args.files
    problem = _animate_files_problem(files)
    if problem is not None:
        print(f"mvcjax animate: {problem}", file=sys.stderr)
        return 2
    _say(f"mvcjax animate: {' '.join(files[:-1])} -> {files[-1]}")
    t0 = time.perf_counter()
    try:
        scene = (mvcjax.motion.Scene.read(files[0]) if len(files) == 2 else
                 mvcjax.motion.Scene.from_files(*files[:3]))
    except (mvcjax.motion.BVHError, mvcjax.motion.ConfigError, FileNotFoundError) as error:
        print(f"mvcjax animate: {error}", file=sys.stderr)
        return 2
    _say(f"  read and rigged {len(scene.actors)} character(s), {scene.frames} frames, in "
         f"{time.perf_counter() - t0:.1f} s")
    solver = mvcjax.FoldFree() if args.fold_free else None
    t0 = time.perf_counter()
    poses = scene.deform(solver)
    _say(f"  deformed in {time.perf_counter() - t0:.1f} s (compiling included)")
    for actor, vertices in zip(scene.actors, poses):
        report = actor.report(vertices)
        _say(f"  {actor.drawing.config.path.parent.name}: joints within "
             f"{report.joint_miss.max():.2f} px, folds in {report.folded_frames:.0%} of "
             f"frames (at most {report.flipped.max()} shape triangles)")
    t0 = time.perf_counter()
    progress = None if args.progress is None else args.progress == "on"
    scene.write(files[-1], vertices=poses, size=args.size, follow=args.follow,
                progress=progress)
    _say(f"  drew and wrote {files[-1]} in {time.perf_counter() - t0:.1f} s")
    return 0


class _Help(argparse.ArgumentDefaultsHelpFormatter):
    """Each option's default after its help, unless the help says it or it is None."""

    def _get_help_string(self, action):
        if action.default is None or "(default:" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mvcjax", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--compile-cache", default=None, metavar="FOLDER",
                        help="keep what the command compiles in this folder (JAX's "
                        "persistent compilation cache), so that the next run loads it; "
                        "'off' for none (default: $MVCJAX_COMPILE_CACHE, else "
                        f"{_default_cache()})")
    _demo_parser(sub, common)
    _dataset_parser(sub, common)
    animate = sub.add_parser(
        "animate", help="move a drawn character by motion capture (AnimatedDrawings' files)",
        description="Read AnimatedDrawings' files (a scene config, or a character folder, "
        "a motion config and a retarget config), retarget the clip onto the character, pose "
        "it every frame and write the animation: .gif, .mp4, .png (animated), .webp, or a "
        "folder of PNG frames for a path without a suffix.",
        formatter_class=_Help, parents=[common])
    animate.add_argument("files", nargs="+", metavar="FILE",
                         help="SCENE.yaml OUT, or CHARACTER MOTION.yaml RETARGET.yaml OUT")
    animate.add_argument("--fold-free", action="store_true",
                         help="solve with mvcjax.FoldFree (no fold, slower)")
    animate.add_argument("--size", type=int, default=None,
                         help="the pictures' longer side (default: the character's pixels)")
    animate.add_argument("--follow", action="store_true",
                         help="move the window with the characters (default: one window "
                              "holds the whole animation)")
    animate.add_argument("--progress", choices=("on", "off"), default=None, help=PROGRESS)
    return parser


def _demo_parser(sub, common) -> None:
    demo = sub.add_parser("demo", help="deform the built-in horse and write a figure",
                          formatter_class=_Help, parents=[common])
    demo.add_argument("--out", default="mvcjax-demo.png", help="PNG figure to write")
    demo.add_argument("--animation", default="mvcjax-demo.gif",
                      help="animation to write (.gif, .png, .webp or .mp4)")
    demo.add_argument("--frames", type=int, default=48, help="frames in the animation")
    demo.add_argument("--layers", default=None,
                      help="also pose a character drawn in layers (its arm across the body "
                           "and back) and write it to this animation file")
    demo.add_argument("--size", type=int, default=320, help="animation side, in pixels")
    demo.add_argument("--shape-spacing", type=float, default=None,
                      help="edge length of the shape mesh (default: the rig's)")
    demo.add_argument("--dpi", type=int, default=110, help="the PNG figure's dots per inch")
    demo.add_argument("--arm-degrees", type=float, default=110.0,
                      help="how far the character's arm turns in the fold panels")


def _dataset_parser(sub, common) -> None:
    dataset = sub.add_parser(
        "dataset", help="pose every sprite of a folder at random and write the pictures",
        description="Rig every sprite of a folder (pictures with alpha, or opaque pictures "
        "keyed from their corner colour), pose each at random within limits (no folds), "
        "and write the posed pictures, masks and handle targets (mvcjax.generate). Run it "
        "again with the same options to finish an interrupted dataset.",
        formatter_class=_Help, parents=[common])
    dataset.add_argument("sprites", help="a folder of sprites, or a label with --glyphs")
    dataset.add_argument("out", help="the folder to write")
    dataset.add_argument("--glyphs", default=None,
                         help="pose these letters of a font instead of a folder's sprites")
    dataset.add_argument("--font", default=None, help="font file for --glyphs (default: "
                         "DejaVu Sans)")
    dataset.add_argument("--glyph-size", type=int, default=96, help="glyph size in pixels")
    dataset.add_argument("--poses", type=int, default=64, help="random poses per sprite")
    dataset.add_argument("--size", type=int, default=128, help="picture side, in pixels")
    dataset.add_argument("--batch", type=int, default=32, help="poses per file")
    dataset.add_argument("--seed", type=int, default=0, help="seed of the random poses")
    for name, text in LIMITS.items():
        dataset.add_argument(f"--{name.replace('_', '-')}", type=float, default=None,
                             help=f"{text} (default: mvcjax.generate.PoseLimits.{name})")
    dataset.add_argument("--folds", action="store_true", help="keep poses that fold")
    dataset.add_argument("--progress", choices=("on", "off"), default=None, help=PROGRESS)
    dataset.add_argument("--coordinator", default=None, help="host:port of process 0, to "
                         "run as one of several processes (jax.distributed)")
    dataset.add_argument("--num-processes", type=int, default=None,
                         help="how many processes, with --coordinator")
    dataset.add_argument("--process-id", type=int, default=None,
                         help="this process's number from 0, with --coordinator")


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    _keep_compiled(args.compile_cache)
    commands = {"demo": _demo, "dataset": _dataset, "animate": _animate}
    return commands[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
