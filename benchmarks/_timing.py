"""Timing helpers shared by the benchmarks: compile once outside the timed region, block
until ready, take the median of many calls."""

from __future__ import annotations

import json
import os
import platform
import time


def spacing_for(shape, vertices: int) -> float:
    """A shape-mesh spacing giving about `vertices` vertices.

    Calibrated on Triangle's q28 meshes of the horse: about `area / (0.513 s^2)` vertices.
    """
    return (shape.area / (0.513 * vertices)) ** 0.5


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
