"""First calls: how long a user waits for a program to compile, each case in a fresh
process, with and without JAX's persistent compilation cache.

Cases: the default `rig.deform` of the built-in horse; each solver on it; `FoldFree` on
the character with a bone per arm, its right arm turned 110 degrees (about 3k shape
vertices); a rig of a new size after the first (its first frame); a renderer's first
picture; a layered character's first pose. Then what a newcomer runs, whole, from the
start of its Python process to its end: the README's example (its Python blocks, in
order, in one script) and the README's `mvcjax demo` command; and, without `--quick`,
the README's first command as written (a fresh virtual environment, `pip install`, the
demo). Each is timed in a new Python process, so
nothing compiled by another case helps it: "cold" with no persistent cache, "cached" in a
second process that finds what the first wrote to a persistent cache directory
(`jax_compilation_cache_dir`, see the guide). The command line keeps its programs in a
cache of its own by default (`--compile-cache`): its cold run starts with that cache
empty, as a user's first run does. The building of the rig is outside the
timed region; the first call, compiling included, is inside. After it, the size of the
program that call runs: the operations of its StableHLO module, as `jax.jit` lowers it
(what XLA then compiles; a whole command has no one program). Targets (seconds, on the
2-core CPU that CI runs on): `FoldFree` 3, the other solvers 1.5, a renderer 1; the
README's example 10, its demo 10, its first command (install included) 40.

    python benchmarks/compile.py [--quick] [--json benchmarks/results/compile-cpu-2core.json]
"""

from __future__ import annotations

import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time

from _timing import quick_and_json, write_results

ROOT = pathlib.Path(__file__).resolve().parent.parent
EXAMPLE, DEMO, FIRST_COMMAND = ("README example, whole", "README's mvcjax demo, whole",
                                "README's first command, install included")
TARGETS_S = {"FoldFree": 3.0, "GaussNewton": 1.5, "Dogleg": 1.5, "LevenbergMarquardt": 1.5,
             "FixedG(anderson=5, stop_early=True)": 1.5, "renderer": 1.0, EXAMPLE: 10.0,
             DEMO: 10.0, FIRST_COMMAND: 40.0}
CASES = ("deform", "GaussNewton", "Dogleg", "LevenbergMarquardt",
         "FixedG(anderson=5, stop_early=True)", "FoldFree", "new rig size", "renderer",
         "character", EXAMPLE, DEMO, FIRST_COMMAND)
# The demo's command line runs in the README's tests (tests/test_cli.py) already.
QUICK_CASES = ("deform", "GaussNewton", "FoldFree", EXAMPLE)
QUICK_CACHED = ("deform",)  # the quick run times the persistent cache on this case only


def _horse():
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    rig = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles())
    return rig, np.asarray(rig.handle_positions + datasets.horse_drag())


def _prepared(case: str):
    """The first call of `case`, as a function of nothing, its inputs built."""
    import jax
    import numpy as np

    import mvcjax
    from mvcjax import datasets

    if case == "FoldFree":
        rig = mvcjax.Rig.build(datasets.character(), datasets.character_bones("arms"))
        targets = np.array(rig.handle_positions)
        targets[5] = datasets._rotate(targets[5], targets[4], 110.0)
        return lambda: rig.deform(targets, mvcjax.FoldFree())
    if case == "character":
        character = mvcjax.Character.build(datasets.layered_figure(),
                                           datasets.layered_figure_handles())
        pose = datasets.layered_figure_wave(4)[1]
        return lambda: character.deform(pose)
    rig, targets = _horse()
    if case == "deform":
        return lambda: rig.deform(targets)
    if case == "new rig size":
        jax.block_until_ready(rig.deform(targets))
        other = mvcjax.Rig.build(datasets.horse(), datasets.horse_handles(),
                                 shape_spacing=4.0)  # about 5k vertices, the first 3k
        return lambda: other.deform(targets)
    if case == "renderer":
        return lambda: mvcjax.Renderer.build(rig, size=(256, 256))(rig.shape_mesh.vertices)
    solver = {"GaussNewton": mvcjax.GaussNewton(), "Dogleg": mvcjax.Dogleg(),
              "LevenbergMarquardt": mvcjax.LevenbergMarquardt(),
              "FixedG(anderson=5, stop_early=True)": mvcjax.FixedG(
                  iterations=300, anderson=5, stop_early=True)}[case]
    return lambda: rig.deform(targets, solver)


def stablehlo_ops(fn) -> int:
    """The size of the program `fn` runs: the operations of its StableHLO module (nested
    regions and called functions included), lowered by `jax.jit` (the library's own
    programs are inlined in a caller's trace)."""
    import jax

    text = jax.jit(fn).lower().as_text()
    return sum(1 for line in text.splitlines()
               if re.match(r"\s*(%[^=]+= )?\"?(stablehlo|chlo)\.", line))


def child(case: str) -> None:
    """Run in the fresh process: print the first call's seconds, and then the size of
    its program, as JSON."""
    import jax

    first = _prepared(case)
    start = time.perf_counter()
    jax.block_until_ready(first())
    seconds = time.perf_counter() - start
    program = _picture() if case == "renderer" else first
    print(json.dumps({"first_s": seconds, "hlo_ops": stablehlo_ops(program)}))


def _picture():
    """The renderer case's program, its picture: the renderer built on the host first
    (a trace cannot build one)."""
    import mvcjax

    rig, _ = _horse()
    renderer = mvcjax.Renderer.build(rig, size=(256, 256))
    return lambda: renderer(rig.shape_mesh.vertices)


def readme_blocks(kind: str) -> list[str]:
    """The README's `kind` fenced blocks ("python", "bash"), each as its lines."""
    blocks, block = [], None
    for line in (ROOT / "README.md").read_text().splitlines():
        if block is None and line.strip() == f"```{kind}":
            block = []
        elif block is not None and line.strip() == "```":
            blocks.append(block)
            block = None
        elif block is not None:
            block.append(line)
    return blocks


def whole_command(case: str, folder: str) -> list[str]:
    """The command line of a whole-command case, run in the empty `folder`."""
    if case == EXAMPLE:
        script = pathlib.Path(folder, "example.py")
        script.write_text("\n\n".join("\n".join(b) for b in readme_blocks("python")))
        return [sys.executable, str(script)]
    first = readme_blocks("bash")[0][0]  # the README's first command, as written
    if case == DEMO:
        return [sys.executable, "-m", "mvcjax", *first.split("mvcjax ", 1)[1].split()]
    return ["bash", "-c", first.replace("pip install .", f"pip install -q {ROOT}")]


def run_case(case: str, cache_dir: str | None) -> tuple[float, int | None]:
    """The first call's seconds in a fresh process, and its program's StableHLO
    operations (None for a whole command)."""
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    if cache_dir is not None:
        env.update(JAX_COMPILATION_CACHE_DIR=cache_dir,
                   JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
                   JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="0")
    if case in (EXAMPLE, DEMO, FIRST_COMMAND):
        with tempfile.TemporaryDirectory() as folder:
            if cache_dir is None:  # the command line's first run: its own cache empty
                env["MVCJAX_COMPILE_CACHE"] = os.path.join(folder, "compile-cache")
            command = whole_command(case, folder)
            start = time.perf_counter()
            subprocess.run(command, env=env, cwd=folder, check=True, capture_output=True)
            return time.perf_counter() - start, None
    out = subprocess.run([sys.executable, __file__, "--child", case], env=env, check=True,
                         capture_output=True, text=True).stdout
    result = json.loads(out.strip().splitlines()[-1])
    return result["first_s"], result["hlo_ops"]


def measure(cases, cached_cases) -> list[dict]:
    rows = []
    for case in cases:
        cold, ops = run_case(case, None)
        cached = None
        if case in cached_cases:  # not FIRST_COMMAND: a fresh environment, no cache
            with tempfile.TemporaryDirectory() as cache:
                run_case(case, cache)  # fills the cache
                cached, _ = run_case(case, cache)
        rows.append({"case": case, "cold_s": cold, "cached_s": cached, "hlo_ops": ops,
                     "target_s": TARGETS_S.get(case)})
        print(rows[-1], flush=True)
    return rows


def format_table(data: dict) -> str:
    lines = ["| first call | cold (s) | with the persistent cache (s) | target (s) | "
             "program (StableHLO ops) |", "|---|---|---|---|---|"]
    for r in data["rows"]:
        target = "" if r["target_s"] is None else (
            f"{r['target_s']:g} ({'met' if r['cold_s'] <= r['target_s'] else 'missed'})")
        cached = "-" if r["cached_s"] is None else f"{r['cached_s']:.2f}"
        ops = "-" if r.get("hlo_ops") is None else f"{r['hlo_ops']:,}"
        lines.append(f"| {r['case']} | {r['cold_s']:.2f} | {cached} | {target} | {ops} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(argv[1])
        return 0
    args = quick_and_json(__doc__, "four cases, one of them with the cache", argv)
    rows = measure(*((QUICK_CASES, QUICK_CACHED) if args.quick else
                     (CASES, set(CASES) - {FIRST_COMMAND})))
    if args.json:
        write_results(args.json, rows, quick=args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main())
