"""Every benchmark in its quick mode, one after another in one process, so that they
cannot rot: what CI runs. Their numbers are printed (and written as JSON), never asserted.

One process shares what the benchmarks have in common: JAX imported once, the built-in
rigs and their programs compiled once. So a quick run's first-call times are not a
user's (`compile.py` times those, each in a fresh process of its own); each benchmark's
own wall time is printed after it, and the whole as a table at the end. `--jobs 2` (CI)
deals the benchmarks to two such processes that run at once, one a core: their times
then share the machine, and what each prints comes after it ends.

    python benchmarks/quick.py [--out DIR] [--only NAME ...] [--jobs N]
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
import time

# (script, its quick arguments): the JSON goes to `<out>/<script>.json`. The smallest
# runs that still take every path: one mesh size where a quick run has two, the allocator
# that keeps freed memory (a second process) in frames.py only.
QUICK = (
    ("deform", ["--quick", "--sizes", "1500", "--repeats", "10"]),
    ("solvers", ["--quick", "--figures", "{out}/figures"]),
    ("frames", ["--quick"]),
    ("animation", ["--quick"]),
    ("compile", ["--quick"]),
    ("throughput", ["--quick", "--sizes", "1500", "--allocator", "default"]),
    ("vmap_rules", ["--quick"]),
    ("interact", ["--quick"]),
    ("live", ["--quick"]),
    ("render", ["--quick", "--sizes", "256"]),
    ("folds", ["--quick"]),
    ("robustness", ["--quick"]),
    ("stack", ["--quick"]),
    ("many_rigs", ["--quick"]),
    ("dataset", ["--quick"]),
    ("drawings", ["--quick"]),
    ("table1", ["--quick", "--repeats", "10", "--figures", "{out}/figures"]),
)


def run(name: str, args: list[str], out: str) -> float:
    """Run benchmark `name` with `args` in this process; its wall seconds."""
    import jax

    module = importlib.import_module(name)
    argv = [a.format(out=out) for a in args] + ["--json", os.path.join(out, f"{name}.json")]
    print(f"\n=== benchmarks/{name}.py {' '.join(argv)}", flush=True)
    start = time.perf_counter()
    try:
        status = module.main(argv)
    finally:
        jax.config.update("jax_enable_x64", False)  # as the next one expects to start
    if status:
        raise SystemExit(f"benchmarks/{name}.py exited with {status}")
    return time.perf_counter() - start


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=os.path.join(os.environ.get("TMPDIR", "/tmp"),
                                                      "mvcjax-benchmarks"),
                        help="the folder for each benchmark's JSON and figures")
    parser.add_argument("--only", nargs="+", choices=[name for name, _ in QUICK],
                        help="these benchmarks only")
    parser.add_argument("--jobs", type=int, default=1,
                        help="deal the benchmarks to this many processes run at once")
    args = parser.parse_args(argv)
    os.makedirs(os.path.join(args.out, "figures"), exist_ok=True)
    names = [name for name, _ in QUICK if not args.only or name in args.only]
    others = [dealt(names[k::args.jobs], k, args.out) for k in range(1, args.jobs)]
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    seconds = {name: run(name, quick_args, args.out) for name, quick_args in QUICK
               if name in names[::args.jobs]}
    print("\n| quick benchmark | wall (s) |\n|---|---|")
    for name, s in seconds.items():
        print(f"| {name} | {s:.1f} |")
    print(f"| all | {sum(seconds.values()):.1f} |", flush=True)
    for process, log in others:
        status = process.wait()
        with open(log) as f:
            print(f"\n=== {log}\n{f.read()}", flush=True)
        if status:
            raise SystemExit(f"benchmarks/quick.py --only ... exited with {status}; see {log}")
    return 0


def dealt(names: list[str], k: int, out: str) -> tuple[subprocess.Popen, str]:
    """Benchmarks `names` started in another process; it and its log file."""
    log = os.path.join(out, f"quick-{k}.log")
    with open(log, "w") as f:
        process = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--out", out,
                                    "--only", *names], stdout=f, stderr=subprocess.STDOUT)
    return process, log


if __name__ == "__main__":
    sys.exit(main())
