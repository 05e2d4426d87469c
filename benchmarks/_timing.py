"""Timing helpers shared by the benchmarks: compile once outside the timed region, block
until ready, take the median of many calls."""

from __future__ import annotations

import json
import os
import platform
import sys
import time


def quick_and_json(doc: str, quick_help: str, argv=None):
    """The arguments of a benchmark that takes only `--quick` and `--json`."""
    import argparse

    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--json", help="write the results to this JSON file")
    return parser.parse_args(argv)


def spacing_for(shape, vertices: int) -> float:
    """A shape-mesh spacing giving about `vertices` vertices.

    Calibrated on Triangle's q28 meshes of the horse: about `area / (0.513 s^2)` vertices.
    """
    return (shape.area / (0.513 * vertices)) ** 0.5


# glibc's malloc keeping freed blocks of up to 1 GiB for reuse, in one arena.
KEEP_FREED_TUNABLES = ("glibc.malloc.mmap_threshold=1073741824:"
                       "glibc.malloc.trim_threshold=1073741824:glibc.malloc.arena_max=1")


def allocator_rows(choice: str, measure, script: str, argv: list[str],
                   child_args: tuple[str, ...] = ()) -> list[dict]:
    """The rows of `measure(allocator)` for glibc's default malloc and for one that keeps
    freed memory (`choice`: "default", "keep_freed" or "both").

    By default glibc maps every block over 32 MiB afresh (and, from threads other than
    the main one, every block over 64 MiB) and unmaps it when freed, so each call of a
    batched program pays the kernel's page faults for its whole result again, a cost
    that grows with the result and dominates large batches. A loop of single frames
    reuses its small blocks. `GLIBC_TUNABLES` is read when a process starts, so the
    "keep_freed" rows come from this script run again with it set (`child_args` added
    to its arguments `argv`, less `--json` and `--allocator`), unless this process
    already runs with it.
    """
    rows = []
    if choice in ("default", "both"):
        if os.environ.get("GLIBC_TUNABLES"):
            print(f"note: GLIBC_TUNABLES={os.environ['GLIBC_TUNABLES']} is set: the "
                  "'default' rows are not glibc's defaults")
        rows += measure("default")
    if choice not in ("keep_freed", "both"):
        return rows
    if platform.libc_ver()[0] != "glibc":
        print("keep_freed: not measured, the C library is not glibc")
        return rows
    if os.environ.get("GLIBC_TUNABLES") == KEEP_FREED_TUNABLES:
        return rows + measure("keep_freed")
    import subprocess
    import tempfile

    kept, skip = [], False
    for arg in argv:
        if skip or arg.split("=")[0] in ("--json", "--allocator"):
            skip = not skip and "=" not in arg
            continue
        kept.append(arg)
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "rows.json")
        subprocess.run([sys.executable, script, *kept, *child_args, "--allocator",
                        "keep_freed", "--json", out], check=True,
                       env={**os.environ, "GLIBC_TUNABLES": KEEP_FREED_TUNABLES})
        with open(out) as f:
            return rows + [r for r in json.load(f)["rows"] if r.get("allocator")]


def median_ms(fn, args_list, repeats: int, budget_s: float = 3.0) -> float:
    """Median wall time in ms of `repeats` calls cycling through `args_list` (fewer, but at
    least 5, past `budget_s`); one untimed call first, every call blocked until ready."""
    import jax
    import numpy as np

    jax.block_until_ready(fn(*args_list[0]))
    times = []
    for i in range(repeats):
        if i >= 5 and sum(times) > budget_s:
            break
        args = args_list[i % len(args_list)]
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def compile_ms(fn, *args) -> float:
    """Wall time in ms of the first (compiling) call."""
    import jax

    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return (time.perf_counter() - t0) * 1e3


def write_results(path: str, rows: list[dict], **meta) -> None:
    """The rows as JSON, with what they were measured on."""
    import jax

    meta = {
        "jax": jax.__version__,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES"),
        "keep_freed_tunables": KEEP_FREED_TUNABLES,
        "device": jax.devices()[0].device_kind,
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        **meta,
    }
    with open(path, "w") as f:
        json.dump({"meta": meta, "rows": rows}, f, indent=2)
    print(f"wrote {path}")


def interleaved_median_ms(fns: dict, repeats: int, budget_s: float = 20.0, block: int = 8) -> dict:
    """Median wall time in ms of each `fns[name] = (fn, args_list)`, timed in turns.

    Each round runs every function `block` times back to back (cycling through its
    arguments) and keeps the times of all but the first call of the block: the steady
    per-frame cost, as in an interactive loop, not the cost of a cache emptied by the
    previous method. Whatever else the machine is doing weighs on all methods alike, so
    their ratios are measured in one run. Each function is called once untimed first
    (compile before). About `repeats` timed calls each, at least 2 rounds, fewer rounds
    past `budget_s`.
    """
    import jax
    import numpy as np

    for fn, args_list in fns.values():
        jax.block_until_ready(fn(*args_list[0]))
    times = {name: [] for name in fns}
    start = time.perf_counter()
    rounds = max(2, -(-repeats // (block - 1)))
    for r in range(rounds):
        if r >= 2 and time.perf_counter() - start > budget_s:
            break
        for name, (fn, args_list) in fns.items():
            for i in range(block):
                args = args_list[(r * block + i) % len(args_list)]
                t0 = time.perf_counter()
                jax.block_until_ready(fn(*args))
                if i:
                    times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t) * 1e3) for name, t in times.items()}
