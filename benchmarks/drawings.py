"""AnimatedDrawings' files to a GIF: a drawn character moved by a motion capture clip
(`mvcjax.motion`), against AnimatedDrawings' own ARAP as the peer of the deformation.

The clip: `dab` (AnimatedDrawings' `fair1` clips) on `char1` with `fair1_ppf.yaml`, at
the character's own resolution (a pixel of its picture per pixel). Rows:

- `files_to_gif`: files read, rigged, retargeted, deformed, drawn and written as a GIF,
  in this process once it has done so before (compiled), with the default solver, and
  each stage's share;
- `command`: `mvcjax animate CHARACTER MOTION RETARGET OUT.gif` as a user runs it, a new
  process (start-up, imports and compiles included), with the default solver and with
  `--fold-free`;
- `per_frame`: one frame's deformation: `rig.deform` (jitted, the clip's frames in turn,
  median), the clip's frames in one `deform_frames` call divided by their number, and the
  peer, AnimatedDrawings' `ARAP.solve` (`animated_drawings/model/arap.py`, numpy and
  scipy) on the same shape mesh pinned at the same joints, median over the frames;
- `poses`: per solver, the flipped shape triangles of every frame, the fraction of
  frames with a fold and the largest joint miss (pixels).

The peer is imported from AnimatedDrawings' source (`--peer PATH`, a checkout of
https://github.com/facebookresearch/AnimatedDrawings; its `examples/` also serve as the
files with `--examples`); without it its row says "missing". `--reference OUT.npz`
writes what AnimatedDrawings' own retargeter computes for the clip (the joints at every
frame, the body parts' depths), the reference `tests/test_motion.py` compares with.

    python benchmarks/drawings.py [--quick] [--peer PATH]
        [--json benchmarks/results/drawings-cpu-2core.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import write_results

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "animated_drawings"
FILES = ("examples/characters/char1", "examples/config/motion/dab.yaml",
         "examples/config/retarget/fair1_ppf.yaml")


def files(examples: Path, frames: int | None, tmp: str) -> tuple[str, str, str]:
    """The character, motion and retarget files; the motion cut to `frames` frames."""
    character, motion, retarget = (str(examples / f) for f in FILES)
    if frames is not None:
        text = Path(motion).read_text().replace("end_frame_idx: 339", f"end_frame_idx: {frames}")
        text = text.replace("filepath: examples/", f"filepath: {examples}/examples/")
        motion = os.path.join(tmp, "motion.yaml")
        Path(motion).write_text(text)
    return character, motion, retarget


def files_to_gif(paths, out: str) -> dict:
    import numpy as np

    from mvcjax import export, motion

    t0 = time.perf_counter()
    scene = motion.Scene.from_files(*paths)
    t1 = time.perf_counter()
    poses = scene.deform()
    t2 = time.perf_counter()
    pictures = scene.pictures(poses, progress=False)
    t3 = time.perf_counter()
    export.write_animation(out, pictures, fps=scene.fps)
    t4 = time.perf_counter()
    return {"frames": scene.frames, "size": list(np.shape(pictures)[1:3]),
            "read_and_rig_s": t1 - t0, "deform_s": t2 - t1, "draw_s": t3 - t2,
            "write_s": t4 - t3, "total_s": t4 - t0}


def command(paths, out: str, fold_free: bool) -> dict:
    args = [sys.executable, "-m", "mvcjax", "animate", *paths, out, "--progress", "off"]
    t0 = time.perf_counter()
    done = subprocess.run(args + (["--fold-free"] if fold_free else []), capture_output=True,
                          text=True)
    seconds = time.perf_counter() - t0
    if done.returncode:
        raise RuntimeError(done.stdout + done.stderr)
    return {"solver": "FoldFree" if fold_free else "default", "seconds": seconds,
            "output": done.stdout.strip().splitlines()}


PEER = """
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from animated_drawings.model.arap import ARAP
data = np.load(sys.argv[2])
t0 = time.perf_counter()
arap = ARAP(data["joints"][0], list(data["faces"]), data["vertices"])
setup = time.perf_counter() - t0
times = []
for frame in data["joints"]:
    t0 = time.perf_counter()
    arap.solve(frame)
    times.append(time.perf_counter() - t0)
print(json.dumps({"peer_ms": float(np.median(times) * 1e3), "peer_setup_s": setup,
                  "peer_numpy": np.__version__}))
"""


def has_peer(peer: Path | None) -> bool:
    return peer is not None and (peer / "animated_drawings" / "model" / "arap.py").is_file()


def per_frame(scene, peer: Path | None, python: str) -> dict:
    import jax
    import numpy as np

    import mvcjax

    actor = scene.actors[0]
    rig = actor.drawing.rig
    targets = actor.targets(scene.frames)
    deform = jax.jit(rig.deform)
    jax.block_until_ready(deform(targets[0]))
    times = []
    for frame in targets:
        t0 = time.perf_counter()
        jax.block_until_ready(deform(frame))
        times.append(time.perf_counter() - t0)
    jax.block_until_ready(mvcjax.deform_frames(rig, targets))
    t0 = time.perf_counter()
    jax.block_until_ready(mvcjax.deform_frames(rig, targets))
    row = {"rig_deform_ms": float(np.median(times) * 1e3),
           "deform_frames_ms": (time.perf_counter() - t0) * 1e3 / len(targets),
           "shape_vertices": int(rig.shape_mesh.vertices.shape[0]),
           "peer": "AnimatedDrawings ARAP" if has_peer(peer) else "missing"}
    if has_peer(peer):
        row.update(peer_per_frame(actor, peer, python))
        row["speedup_rig_deform"] = row["peer_ms"] / row["rig_deform_ms"]
        row["speedup_deform_frames"] = row["peer_ms"] / row["deform_frames_ms"]
    return row


def peer_per_frame(actor, peer: Path, python: str) -> dict:
    """AnimatedDrawings' ARAP on the rig's shape mesh, pinned at the joints (as it pins
    its own mesh), in its units (the picture's larger side 1), run by `python` (it needs
    numpy 1)."""
    import numpy as np

    mesh = actor.drawing.rig.shape_mesh
    unit = max(actor.drawing.config.size)
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "peer.npz")
        np.savez(data, joints=(np.asarray(actor.motion.joints()) / unit).astype(np.float32),
                 faces=np.asarray(mesh.faces).astype(np.int32),
                 vertices=(np.asarray(mesh.vertices) / unit).astype(np.float32))
        done = subprocess.run([python, "-c", PEER, str(peer), data], capture_output=True,
                              text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def poses(scene, fold_free: bool) -> list[dict]:
    import mvcjax

    rows = []
    for name, solver in [("default", None)] + ([("FoldFree", mvcjax.FoldFree())]
                                               if fold_free else []):
        t0 = time.perf_counter()
        (vertices,) = scene.deform(solver)
        seconds = time.perf_counter() - t0
        report = scene.actors[0].report(vertices)
        rows.append({"kind": "poses", "solver": name, "deform_s": seconds,
                     "flipped_per_frame": report.flipped.tolist(),
                     "folded_frames": report.folded_frames,
                     "most_flipped": int(report.flipped.max()),
                     "joint_miss_px": float(report.joint_miss.max())})
    return rows


def write_reference(peer: Path, examples: Path, out: str) -> None:
    """AnimatedDrawings' retargeted joints `(frames, j, 2)` (its rig's, in pixels, y up,
    from the root), its root's path `(frames, 2)` and body part depths `(frames, parts)`
    for the clip."""
    import numpy as np

    sys.path.insert(0, str(peer))
    np.bool8 = np.bool_
    from animated_drawings.config import CharacterConfig, MotionConfig, RetargetConfig
    from animated_drawings.model import quaternions
    from animated_drawings.model.animated_drawing import AnimatedDrawing, AnimatedDrawingRig

    # Its numpy 1 code takes the square root of a one-element array.
    quaternions.math = type("math", (), {"sqrt": staticmethod(
        lambda x: math.sqrt(float(np.squeeze(x))))})
    os.chdir(examples)
    char, mot, ret = (CharacterConfig(FILES[0] + "/char_cfg.yaml"), MotionConfig(FILES[1]),
                      RetargetConfig(FILES[2]))
    drawing = AnimatedDrawing.__new__(AnimatedDrawing)
    drawing.char_cfg, drawing.retarget_cfg = char, ret
    drawing.rig = AnimatedDrawingRig(char)
    drawing._modify_retargeting_cfg_for_character()
    drawing._initialize_retargeter_bvh(mot, ret)
    retargeter = drawing.retargeter
    joints, roots, depths = [], [], []
    for frame in range(retargeter.bvh.frame_max_num):
        angles, joint_depths, root = retargeter.get_retargeted_frame_data(
            frame * retargeter.bvh.frame_time)
        drawing.rig.root_joint.set_position(root)
        drawing.rig.set_global_orientations(angles)
        joints.append((drawing.rig.get_joints_2D_positions() - root[:2]) * char.img_dim)
        roots.append((root[:2] - np.array(ret.char_start_loc[:2])) * char.img_dim)
        depths.append([np.mean([joint_depths[d] for d in part["bvh_depth_drivers"]])
                       for part in ret.char_bodypart_groups])
    np.savez_compressed(out, joints=np.array(joints, np.float32),
                        roots=np.array(roots, np.float32),
                        depths=np.array(depths, np.float32))
    print(f"wrote {out}")


def format_table(data: dict, source: str) -> str:
    """The docs' table (`docs/drawings.md`): the clip's timings, per frame against the
    peer, and its folds, from a results file of this script."""
    rows = {(r["kind"], r.get("solver")): r for r in data["rows"]}
    gif = rows[("files_to_gif", None)]
    frame = rows[("per_frame", None)]
    meta = data["meta"]
    lines = [f"From `{source}`: {gif['frames']} frames of `{meta['clip']}` on "
             f"`{meta['character']}`, {gif['size'][1]}x{gif['size'][0]} pixels, "
             f"{frame['shape_vertices']:,} shape vertices; {meta['cpu_count']} cores "
             f"({meta['device']}), JAX {meta['jax']}" + (", quick run." if meta.get("quick")
                                                       else "."), "",
             "| what | time |", "|---|---|"]
    for name, solver in (("default", "default"), ("`--fold-free`", "FoldFree")):
        if ("command", solver) in rows:
            lines.append(f"| `mvcjax animate` with the {name} solver, as run (start-up, "
                         f"compiles) | {rows[('command', solver)]['seconds']:.1f} s |")
    lines += [f"| files to GIF in a warm process, default solver | {gif['total_s']:.2f} s "
              f"(read and rig {gif['read_and_rig_s']:.2f}, deform {gif['deform_s']:.2f}, "
              f"draw {gif['draw_s']:.2f}, write {gif['write_s']:.2f}) |",
              f"| a frame: `rig.deform`, jitted | {frame['rig_deform_ms']:.2f} ms |",
              f"| a frame: the clip in one `deform_frames` | "
              f"{frame['deform_frames_ms']:.3f} ms |"]
    if "peer_ms" in frame:
        lines += [f"| a frame: AnimatedDrawings' ARAP (peer), same mesh and joints | "
                  f"{frame['peer_ms']:.1f} ms ({frame['speedup_rig_deform']:.0f}x "
                  f"`rig.deform`, {frame['speedup_deform_frames']:.0f}x `deform_frames`) |"]
    lines += ["", "| solver | frames with a fold | most flipped triangles in a frame | "
              "joint miss (px) | deform time |", "|---|---|---|---|---|"]
    for (kind, solver), r in rows.items():
        if kind == "poses":
            lines.append(f"| {solver} | {r['folded_frames']:.0%} | {r['most_flipped']} | "
                         f"{r['joint_miss_px']:.2f} | {r['deform_s']:.1f} s |")
    return "\n".join(lines)


def format_examples_table(data: dict, source: str) -> str:
    """The docs' table of every example character and clip: their folds."""
    lines = [f"From `{source}` (default solver, `fair1_ppf.yaml`).", "",
             "| character | clip | frames | frames with a fold | most flipped triangles | "
             "joint miss (px) |", "|---|---|---|---|---|---|"]
    for r in data["rows"]:
        name = r["character"] if r["scene"] == r["character"] else f"{r['character']} (scene)"
        lines.append(f"| {name} | {r['clip']} | {r['frames']} | {r['folded_frames']:.0%} | "
                     f"{r['most_flipped']} | {r['joint_miss_px']:.2f} |")
    return "\n".join(lines)


CLIPS = ("dab", "jumping", "wave_hello", "zombie")
SHEET_FRAMES = 8


def sheets(examples: Path, out: Path, size: int = 200) -> list[dict]:
    """For every character of `examples/characters` and every `fair1` clip (with
    `fair1_ppf.yaml`), and for the two-character scene: a strip of `SHEET_FRAMES`
    frames spread over the clip (one PNG per character, a row per clip; the window
    follows the character), and the folds of every frame with the default solver."""
    import numpy as np

    from mvcjax import export, motion

    out.mkdir(parents=True, exist_ok=True)
    rows = []
    retarget = examples / "examples/config/retarget/fair1_ppf.yaml"
    for character in sorted((examples / "examples/characters").glob("char[1-4]")):
        strips = []
        for clip in CLIPS:
            scene = motion.Scene.from_files(
                character, examples / f"examples/config/motion/{clip}.yaml", retarget)
            strips.append(_strip(scene, size, rows, character.name, clip))
        export.write_image(out / f"drawings-{character.name}.png", np.concatenate(strips, 0))
    scene = motion.Scene.read(examples / "examples/config/mvc/multiple_characters_example.yaml")
    export.write_image(out / "drawings-two-characters.png",
                       _strip(scene, size, rows, "char1 + char2", "dab"))
    return rows


def _strip(scene, size: int, rows: list, character: str, clip: str):
    """`SHEET_FRAMES` pictures of the scene side by side; its folds added to `rows`."""
    import numpy as np

    poses = scene.deform()
    for actor, vertices in zip(scene.actors, poses):
        report = actor.report(vertices)
        rows.append({"kind": "example", "character": actor.drawing.config.path.parent.name,
                     "scene": character, "clip": clip, "frames": scene.frames,
                     "folded_frames": report.folded_frames,
                     "most_flipped": int(report.flipped.max()),
                     "joint_miss_px": float(report.joint_miss.max())})
    shown = np.linspace(0, scene.frames - 1, SHEET_FRAMES).round().astype(int)
    pictures = scene.pictures([v[shown] for v in poses], size=size, follow=True,
                              progress=False)
    print(character, clip, rows[-1])
    square = np.zeros((len(pictures), size, size, 4), np.uint8)
    top, left = (size - pictures.shape[1]) // 2, (size - pictures.shape[2]) // 2
    square[:, top:top + pictures.shape[1], left:left + pictures.shape[2]] = pictures
    return np.concatenate(list(square), 1)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="30 frames, the default solver only, for CI")
    parser.add_argument("--peer", type=Path, default=os.environ.get("ANIMATED_DRAWINGS"),
                        help="AnimatedDrawings' source (default $ANIMATED_DRAWINGS)")
    parser.add_argument("--peer-python", default=sys.executable,
                        help="the Python that runs the peer (numpy 1, as it needs)")
    parser.add_argument("--examples", type=Path, default=DATA,
                        help="the folder holding AnimatedDrawings' examples/")
    parser.add_argument("--reference", help="write AnimatedDrawings' retargeting here")
    parser.add_argument("--sheets", type=Path, help="write strips of frames of every "
                        "example character and clip here (with --examples, a checkout)")
    parser.add_argument("--json", help="write the results to this JSON file")
    args = parser.parse_args(argv)
    if args.reference:
        write_reference(args.peer, args.examples.resolve(), os.path.abspath(args.reference))
        return 0
    if args.sheets:
        rows = sheets(args.examples.resolve(), args.sheets)
        if args.json:
            write_results(args.json, rows, clips=list(CLIPS), retarget="fair1_ppf")
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        paths = files(args.examples.resolve(), 30 if args.quick else None, tmp)
        gif = os.path.join(tmp, "dab.gif")
        for solver in (False,) if args.quick else (False, True):
            rows.append({"kind": "command", **command(paths, gif, solver)})
            print(rows[-1]["solver"], f"command {rows[-1]['seconds']:.1f} s")
        files_to_gif(paths, gif)
        rows.append({"kind": "files_to_gif", **files_to_gif(paths, gif)})
        print(f"files to gif (compiled): {rows[-1]['total_s']:.2f} s")
        from mvcjax import motion

        scene = motion.Scene.from_files(*paths)
        rows.append({"kind": "per_frame", **per_frame(scene, args.peer, args.peer_python)})
        print({k: v for k, v in rows[-1].items()})
        rows += poses(scene, fold_free=not args.quick)
    if args.json:
        write_results(args.json, rows, quick=args.quick, clip="dab", character="char1")
    return 0


if __name__ == "__main__":
    sys.exit(main())
