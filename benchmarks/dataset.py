"""Posed datasets: pictures written per second by `mvcjax.generate.write_dataset` (what
`mvcjax dataset` runs), at 128x128 and 256x256, on one process and device, on two CPU
devices of one process, and on two processes of one `jax.distributed` job.

Sprites: glyphs of DejaVu Sans (`generate.glyph_sprites`, 96 pixels), drawn filled, each
rigged with the default options and posed at random within the default limits. Each
setting runs in a fresh process (as a user's command does), writing a new folder twice:
the first pass pays for meshing and for compiling the programs of every new rig size; the
second, with another seed, finds the programs compiled. Pictures per second are the
pictures written over the wall time of the slowest process, everything included; the
report's stages say where the time went.

    python benchmarks/dataset.py [--quick] [--json benchmarks/results/dataset-cpu-2core.json]
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
import time

from _timing import quick_and_json, write_results

LETTERS = "AbCdEfGhKm"
QUICK_LETTERS = "Ab"


def _child(argv: list[str]) -> int:
    """One process of a setting: write the dataset twice, print the two reports."""
    letters, size, poses, out, index, count, port = argv
    import jax

    if int(count) > 1:
        jax.distributed.initialize(coordinator_address=f"localhost:{port}",
                                   num_processes=int(count), process_id=int(index))
    from mvcjax import generate

    sprites = generate.glyph_sprites(letters, size=96)
    reports = []
    for seed in (0, 1):
        report = generate.write_dataset(sprites, f"{out}/seed{seed}", poses=int(poses),
                                        size=int(size), seed=seed, progress=False)
        reports.append({"written": report.written, "seconds": report.seconds,
                        "stages": report.stages, "rejected": report.rejected})
    print("REPORTS " + json.dumps(reports), flush=True)
    return 0


def run_setting(letters: str, size: int, poses: int, devices: int, processes: int) -> dict:
    """Run one setting in fresh processes; its row."""
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}",
           "JAX_PLATFORMS": "cpu"}
    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        runs = [subprocess.Popen([sys.executable, __file__, "--child", letters, str(size),
                                  str(poses), out, str(i), str(processes), str(port)],
                                 env=env, stdout=subprocess.PIPE, text=True)
                for i in range(processes)]
        outputs = [run.communicate()[0] for run in runs]
        wall = time.perf_counter() - start
    if any(run.returncode for run in runs):
        raise RuntimeError(f"a process of the setting failed: {outputs}")
    reports = [json.loads(line.split(" ", 1)[1]) for o in outputs for line in o.splitlines()
               if line.startswith("REPORTS ")]
    row = {"size": size, "devices_per_process": devices, "processes": processes,
           "sprites": len(letters), "poses": poses, "wall_s": wall}
    for i, name in enumerate(("first", "second")):
        passes = [r[i] for r in reports]
        written = sum(p["written"] for p in passes)
        slowest = max(p["seconds"] for p in passes)
        row[f"{name}_pass"] = {
            "pictures": written, "seconds": slowest,
            "pictures_per_second": written / slowest,
            "stages_s": {k: max(p["stages"][k] for p in passes)
                         for k in passes[0]["stages"]},
            "rejected": sum(p["rejected"] for p in passes),
        }
    return row


def format_table(data: dict) -> str:
    head = ("| pictures | processes x devices | pictures written | per second, new rig sizes "
            "| per second, sizes compiled | where the compiled pass's time went: rig / pose "
            "/ draw / write |")
    lines = [head, "|---|---|---|---|---|---|"]
    for r in data["rows"]:
        first, second = r["first_pass"], r["second_pass"]
        stages = " / ".join(f"{second['stages_s'][k]:.2f} s"
                            for k in ("rig", "pose", "draw", "write"))
        lines.append(f"| {r['size']}x{r['size']} | {r['processes']} x "
                     f"{r['devices_per_process']} | {first['pictures']} | "
                     f"{first['pictures_per_second']:.1f} | "
                     f"{second['pictures_per_second']:.0f} | {stages} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--child":
        return _child(argv[1:])
    args = quick_and_json(__doc__, "2 glyphs of 32 poses, one process, instead of 10 of 64",
                          argv)
    letters, poses = (QUICK_LETTERS, 32) if args.quick else (LETTERS, 64)
    settings = [(128, 1, 1), (256, 1, 1)]
    if not args.quick:
        settings += [(128, 2, 1), (128, 1, 2)]
    start = time.perf_counter()
    rows = []
    for size, devices, processes in settings:
        rows.append(run_setting(letters, size, poses, devices, processes))
        print(json.dumps(rows[-1]), flush=True)
    if args.json:
        write_results(args.json, rows, benchmark="dataset", quick=args.quick,
                      seconds=time.perf_counter() - start)
    print(format_table({"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
