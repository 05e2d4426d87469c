"""The tables of the docs, written from the results in `benchmarks/results/*.json`.

Every measured number of the documentation lives in a results file that a benchmark
script wrote; this script writes each table of the docs from one of them, between the
page's lines `<!-- NAME-table:start -->` and `<!-- NAME-table:end -->`, and `--check`
fails, naming the page and the table, where a page differs from what its results give
(a table edited by hand, or results rerun without the tables). CI runs the check, and
`tests/test_tables.py` runs it in the test suite.

    python tools/tables.py           # rewrite every table from the results
    python tools/tables.py --check   # exit 1 if a table is stale, naming it

The pages and their tables: `docs/benchmarks.md` (deform, solvers, animation, frames, throughput,
many rigs, stack, interact, render), `docs/paper.md` (table1), `docs/folds.md` (folds, written by
`folds.format_tables` as `benchmarks/folds.py --table ... --docs ...` writes it) and
`docs/robustness.md` (robustness, once its results file exists), `docs/guide.md`
(jit-method, in its design notes) and `docs/drawings.md` (drawings, drawings-examples).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable
from pathlib import Path

# The benchmarks write the results and know their tables' form.
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import animation
import compile as compile_times
import dataset
import drawings
import folds
import jit_method
import many_rigs
import robustness
import solvers
import stack
import table1
import throughput
import vmap_rules

ROOT = Path(__file__).resolve().parent.parent
RESULTS = "benchmarks/results"


# ---- numbers --------------------------------------------------------------------------


def _num(value, unit: str = "", digits: int = 3) -> str:
    """`value` to about `digits` significant digits (never in exponent form), with its
    unit; "-" where it was not measured."""
    if value is None:
        return "-"
    magnitude = abs(value)
    decimals = 0
    while decimals < 6 and magnitude and magnitude < 10 ** (digits - 1 - decimals):
        decimals += 1
    text = f"{value:,.{decimals}f}" if magnitude >= 10_000 else f"{value:.{decimals}f}"
    return f"{text} {unit}".rstrip()


def _ms(value) -> str:
    return _num(value, "ms")


def _seconds(ms, digits: int = 2) -> str:
    return _num(ms / 1e3, "s", digits)


def _times(value) -> str:
    return "-" if value is None else _num(value) + "x"


def _met(flag) -> str:
    return "-" if flag is None else ("met" if flag else "**missed**")


def _measured_on(data: dict, source: str, *extra: str) -> str:
    """The sentence that says where a table's numbers come from."""
    meta = data.get("meta", {})
    parts = [f"{meta.get('cpu_count', '?')} cores ({meta.get('device', '?')})",
             f"JAX {meta.get('jax', '?')}", *extra]
    if meta.get("quick"):
        parts.append("quick run")
    return f"From `{source}`: measured on " + ", ".join(parts) + "."


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return (["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            + ["| " + " | ".join(row) + " |" for row in rows])


# ---- the tables -------------------------------------------------------------------------


def deform_table(data: dict, source: str) -> str:
    """`benchmarks/deform.py`: per frame, by dtype and shape-mesh size."""
    rows = []
    for r in data["rows"]:
        steps = r.get("gauss_newton_steps")
        rows.append([
            r["dtype"], str(r["shape_vertices"]), str(r["control_vertices"]),
            _num(r["preprocess_s"], "s"), _ms(r["fixed_g15_compile_ms"]),
            _ms(r["fixed_g15_solve_ms"]), _ms(r["fixed_g15_skin_ms"]),
            f"**{_ms(r['fixed_g15_frame_ms'])}**", _ms(r["fixed_g15_frame_rig_argument_ms"]),
            _ms(r.get("default_frame_ms")),
            _ms(r.get("gauss_newton_frame_ms")) + (f" ({steps})" if steps is not None else ""),
        ])
    head = ["dtype", "V_S", "V_C", "preprocess", "paper: compile", "solve", "skin", "frame",
            "frame, rig as argument", "default frame", "GaussNewton frame (steps)"]
    repeats = data.get("meta", {}).get("repeats")
    return "\n".join([_measured_on(data, source, f"medians of {repeats} calls"), "",
                      *_table(head, rows)])


def solvers_table(data: dict, source: str) -> str:
    """`benchmarks/solvers.py`: every solver on every model, `solvers.format_table`."""
    out = [_measured_on(data, source, data.get("meta", {}).get("dtype", "?"),
                        f"gap {data.get('meta', {}).get('gap', '?'):g}"), ""]
    for result in data["rows"]:
        title, table = solvers.format_table(result).split("\n", 1)
        out += [f"**{title}**", "", table, ""]
        targets = result.get("targets", {})
        best = targets.get("best_optimistix")
        if best is not None:
            out += [f"Fastest optimistix solver to the gap: `{best}`, in "
                    f"{_num(targets['best_optimistix_time_over_fixed_g'])} of plain "
                    "fixed-G's time."
                    + ("" if targets.get("anderson_steps_over_fixed_g") is None else
                       f" Anderson takes {_num(targets['anderson_steps_over_fixed_g'])} of "
                       "plain fixed-G's steps."), ""]
    return "\n".join(out).rstrip()


def frames_table(data: dict, source: str) -> str:
    """`benchmarks/frames.py`: `deform_frames` against a loop of single frames."""
    rows = []
    for r in data["rows"]:
        rows.append([
            str(r["frames"]), "keeps freed" if r.get("allocator") == "keep_freed" else "default",
            _ms(r["batch_ms"]), _num(r["batch_frames_per_s"]),
            _num(r.get("batch_out_frames_per_s")), _num(r.get("loop_frames_per_s")),
            _times(r.get("speedup")), _times(r.get("out_speedup")),
            _ms(r["batch_compile_ms"]),
        ])
    meta = data.get("meta", {})
    r0 = data["rows"][0]
    head = ["frames", "malloc", "batch", "frames/s", "`out=`, frames/s", "loop, frames/s",
            "batch / loop", "`out=` / loop", "compile"]
    return "\n".join([
        _measured_on(data, source, f"{r0['shape_vertices']} shape vertices",
                     f"chunks of {r0['chunk']} frames", f"medians of {meta.get('repeats')} calls"),
        "", *_table(head, rows)])


PATHS = {
    "vmap_deform": "`vmap(rig.deform)`",
    "deform_frames": "`deform_frames`",
    "deform_frames_out": "`deform_frames(..., out=)`",
    "vmap_solve": "`vmap(rig.solve)`",
    "vmap_skin": "`vmap(rig.skin)`",
}


def _malloc(row) -> str:
    return "keeps freed" if row.get("allocator") == "keep_freed" else "default"


def throughput_frame_table(data: dict, source: str) -> str:
    """`benchmarks/throughput.py`, the bandwidth and the frame part."""
    bandwidth = next((r for r in data["rows"] if r.get("part") == "bandwidth"), {})
    frames = [r for r in data["rows"] if r.get("part") == "frame"]
    rows = [[
        str(r["shape_vertices"]), r["skinning"], f"**{_ms(r['frame_ms'])}**",
        _ms(r["frame_rig_argument_ms"]), _ms(r["skin_ms"]),
        f"{_seconds(r['compile_ms'], 1)} ({_seconds(r['rig_argument_compile_ms'], 1)})",
        _ms(r["floor_ms"]), f"{r['fraction_of_floor']:.0%}", _times(r.get("blended_over_mvc")),
    ] for r in frames]
    head = ["V_S", "skinning", "frame, `jax.jit(rig.deform)`", "rig as argument", "skin",
            "compile (as argument)", "floor", "of the floor", "blended / mvc"]
    targets = [f"a frame at {r['shape_vertices']} shape vertices within "
               f"{_ms(r['target_frame_ms'])}: {_met(r['target_met'])}"
               for r in frames if "target_frame_ms" in r]
    ratios = [r["blended_over_mvc"] for r in frames if "blended_over_mvc" in r]
    if ratios:
        targets.append(f"blended within {throughput.TARGET_BLENDED_OVER_MVC:g} times mvc: "
                       + _met(max(ratios) <= throughput.TARGET_BLENDED_OVER_MVC))
    return "\n".join([
        _measured_on(data, source, f"about {data.get('meta', {}).get('repeats')} calls each"),
        "",
        f"Bandwidth: {_num(bandwidth.get('jax_scale_gb_s'), 'GB/s')} (a jitted `x * 2` in "
        f"place), {_num(bandwidth.get('numpy_copy_gb_s'), 'GB/s')} (numpy's `copyto`).",
        "", *_table(head, rows), "", "Targets: " + "; ".join(targets) + "."])


def throughput_batch_table(data: dict, source: str) -> str:
    """`benchmarks/throughput.py`, the batch part: every batched path against its loop."""
    batches = [r for r in data["rows"] if r.get("part") == "batch"]
    rows = []
    for size in dict.fromkeys(r["shape_vertices"] for r in batches):
        for key, label in PATHS.items():
            for r in batches:
                if r["shape_vertices"] != size or f"{key}_ms" not in r:
                    continue
                rows.append([str(size), label, _malloc(r), _ms(r[f"{key}_ms"]),
                             _num(r["frames"] / r[f"{key}_ms"] * 1e3),
                             _ms(r[f"{key}_loop_ms"]), _times(r[f"{key}_speedup"])])
    count = batches[0]["frames"] if batches else "?"
    head = ["V_S", f"path ({count} frames)", "malloc", "batch", "frames/s", "loop",
            "batch / loop"]
    return "\n".join([_measured_on(data, source), "", *_table(head, rows)])


def _share(value) -> str:
    return "-" if value is None else f"{value:.0%}"


def throughput_floors_table(data: dict, source: str) -> str:
    """`benchmarks/throughput.py`, the floors of the batches and the ratios they leave."""
    batches = [r for r in data["rows"] if r.get("part") == "batch"]
    rows = [[
        str(r["shape_vertices"]), _malloc(r), _ms(r.get("floor_result_fresh_ms")),
        _ms(r.get("floor_result_reused_ms")), _ms(r.get("floor_solve_products_ms")),
        _ms(r["vmap_deform_loop_ms"]), _times(r.get("ceiling_fresh_speedup")),
        _times(r.get("ceiling_reused_speedup")), _share(r.get("share_of_ceiling")),
        _share(r.get("out_share_of_ceiling")), _met(r.get("target_met")),
    ] for r in batches]
    head = ["V_S", "malloc", "new result", "reused result", "the solve's products", "loop",
            "at best, new result", "at best, `out=`", "vmap and `deform_frames`, of their best",
            "`out=`, of its best", "both at 80% or more"]
    return "\n".join([_measured_on(data, source), "", *_table(head, rows)])


def interact_table(data: dict, source: str) -> str:
    """`benchmarks/interact.py`: updates of a drag in `mvcjax.interact`."""
    rows_in = data["rows"]
    folds_measured = any("show_folds" in r for r in rows_in)
    pins_measured = any("pin_add_ms" in r for r in rows_in)
    rows = []
    for r in rows_in:
        row = [f"{r['shape_vertices']:,}",
               "filled" if r["mode"] == "mesh" else f"textured {r.get('size') or ''}".strip()]
        if folds_measured:
            row.append({True: "shown", False: "off"}.get(r.get("show_folds"), "-"))
        row += [_ms(r["update_ms"]), f"{r['updates_per_s']:.0f}", _ms(r["pose_ms"]),
                _ms(r["drawing_ms"]), _ms(r["full_redraw_ms"]),
                str(r["compilations_while_dragging"]), _seconds(r["first_pose_ms"])]
        if folds_measured:
            row.append(_ms(r.get("folded_update_ms")))
        if pins_measured:
            row += [_ms(r.get("pin_add_ms")), _ms(r.get("pin_remove_ms")),
                    str(r.get("compilations_while_pinning", "-"))]
        rows.append(row)
    head = ["shape vertices", "drawn", *(["folds"] if folds_measured else []), "update",
            "updates a second", "compiled pose", "drawing", "full redraw",
            "compilations while dragging", "first pose (compiles)",
            *(["update while folded"] if folds_measured else []),
            *(["pin added, click to pose", "pin removed", "compilations while pinning"]
              if pins_measured else [])]
    meta = data.get("meta", {})
    target = rows_in[0].get("target_updates_per_s") if rows_in else None
    met = [r["target_met"] for r in rows_in if "target_met" in r]
    lines = [_measured_on(data, source, f"{meta.get('canvas', '?')} canvas"
                          + (f", solver {meta['solver']}" if "solver" in meta else "")),
             "", *_table(head, rows)]
    if target is not None:
        lines += ["", f"Target, at least {target:g} updates a second: met in {sum(met)} of "
                  f"{len(met)} rows."]
    return "\n".join(lines)


def render_table(data: dict, source: str) -> str:
    """`benchmarks/render.py`, the render part: frames, batches and loops."""
    rows = [[
        str(r["shape_vertices"]), r["size"].replace("x", " x "), str(r["tile"]),
        _seconds(r["compile_ms"]), f"**{_ms(r['single_ms'])}**",
        _ms(r["no_antialias_single_ms"]), str(r["batch"]), _ms(r["batch_frame_ms"]),
        _ms(r["map_frame_ms"]), _ms(r["loop_frame_ms"]), _times(r["map_over_loop_throughput"]),
        _times(r["vmap_over_map_throughput"]),
    ] for r in data["rows"] if r.get("kind") == "render"]
    head = ["V_S", "size", "tile", "compile", "frame", "frame, no antialias", "B",
            "vmap, per frame", "lax.map, per frame", "loop, per frame", "loop / lax.map",
            "lax.map / vmap"]
    meta = data.get("meta", {})
    targets = []
    if "frame_ms_512_6k" in meta:
        targets.append(f"a 512 x 512 frame at 6k vertices within "
                       f"{_ms(meta['target_frame_ms_512_6k'])}: {_met(meta['frame_target_met'])}"
                       f" ({_ms(meta['frame_ms_512_6k'])})")
    if "vmap_over_map_worst" in meta:
        targets.append(f"`jax.vmap(renderer)` as fast as `Renderer.frames` (at least "
                       f"{meta['target_vmap_over_map']:g} times its throughput, the runs' "
                       f"noise): {_met(meta['vmap_target_met_everywhere'])} (worst "
                       f"{_times(meta['vmap_over_map_worst'])}"
                       + (f", median {_times(meta['vmap_over_map_median'])}"
                          if "vmap_over_map_median" in meta else "")
                       + ("; the two compile to the same program at every size"
                          if meta.get("vmap_same_program_as_map_everywhere") else "")
                       + ")")
    lines = [_measured_on(data, source, f"medians of {meta.get('repeats')} calls"), "",
             *_table(head, rows)]
    if targets:
        lines += ["", "Targets: " + "; ".join(targets) + "."]
    against = [r for r in data["rows"] if r.get("kind") == "render" and "baseline_ref" in r]
    for r in against:
        size = r["size"].replace("x", " x ")
        lines += ["", f"Against the renderer at commit `{r['baseline_ref']}`, the {size} "
                  f"frame at {r['shape_vertices']} vertices timed in turns in the same run: "
                  f"{_ms(r['interleaved_single_ms'])} now, {_ms(r['baseline_single_ms'])} "
                  f"before, {_times(r['speedup_over_baseline'])} as fast (the pictures differ "
                  f"by at most {r['baseline_max_pixel_difference']:.1e})."]
    return "\n".join(lines)


def render_peers_table(data: dict, source: str) -> str:
    """`benchmarks/render.py`, the peer part: the same pose drawn by other tools."""
    peers = [r for r in data["rows"] if r.get("kind") == "peer"]
    rows = []
    for r in peers:
        if "estimate_ms" in r:
            parts = f"{_ms(r['estimate_ms'])} + {_ms(r['warp_ms'])}"
        else:
            parts = (f"{_ms(r['triangulate_ms'])} + {_ms(r['interpolate_ms'])} + "
                     f"{_ms(r['sample_ms'])}")
        rows.append([
            r["peer"], f"{r['size'].replace('x', ' x ')}, {r['shape_vertices']}",
            f"{parts} = {_ms(r['peer_ms'])}", _ms(r["mvcjax_ms"]),
            _times(r["peer_over_mvcjax"]),
            f"{r['interior_max_abs_diff']:.1e} / {r['interior_mean_abs_diff']:.1e}",
            f"{r['interior_pixels']:,}", _num(r["edge_max_abs_diff"]),
            f"{r['peer_only_pixels']:,}",
        ])
    head = ["peer", "size, V_S", "peer time (parts)", "mvcjax frame", "peer / mvcjax",
            "inside: max / mean difference", "inside pixels", "edges: max difference",
            "drawn by the peer only"]
    lines = [_measured_on(data, source), "", *_table(head, rows)]
    for r in peers:
        if "mvcjax_texel_error_max" in r:
            lines += ["", f"mvcjax's texture positions against {r['peer'].split()[0]}'s: "
                      f"max {r['mvcjax_texel_error_max']:.1e}, mean "
                      f"{r['mvcjax_texel_error_mean']:.1e} texels."]
    return "\n".join(lines)


def render_layers_table(data: dict, source: str) -> str:
    """`benchmarks/render.py`, the layers part: layered characters against one silhouette."""
    layered = [r for r in data["rows"] if r.get("kind") == "layers"]
    rows = [[str(r["parts"]), f"{r['shape_vertices']} / {r['silhouette_shape_vertices']}",
             r["size"].replace("x", " x "), _num(r["build_s"], "s"),
             _seconds(r["deform_compile_ms"]), _ms(r["deform_ms"]),
             _ms(r["silhouette_deform_ms"]), _times(r["deform_over_silhouette"]),
             _seconds(r["render_compile_ms"]), f"**{_ms(r['render_ms'])}**",
             _ms(r["silhouette_render_ms"]), _times(r["render_over_silhouette"])]
            for r in layered]
    head = ["parts", "V_S (layers / one silhouette)", "size", "build", "pose compile",
            "pose", "pose, one silhouette", "ratio", "picture compile", "picture",
            "picture, one silhouette", "ratio"]
    meta = data.get("meta", {})
    lines = [_measured_on(data, source, f"medians of {meta.get('repeats')} calls"), "",
             *_table(head, rows)]
    against = [r for r in layered if "baseline_ref" in r]
    if against:
        lines += ["", f"Against the renderer at commit `{against[0]['baseline_ref']}`, each "
                  "picture timed in turns in the same run: " + "; ".join(
                      f"{r['parts']} parts {_ms(r['interleaved_single_ms'])} now, "
                      f"{_ms(r['baseline_single_ms'])} before "
                      f"({_times(r['speedup_over_baseline'])})" for r in against) + "."]
    return "\n".join(lines)


def render_export_table(data: dict, source: str) -> str:
    """`benchmarks/render.py`, the export part: an animation written in every format."""
    names = {".gif": "GIF", ".png": "animated PNG", ".webp": "WebP", ".mp4": "MP4"}
    exports = [r for r in data["rows"] if r.get("kind") == "export"]
    rows = [[names.get(r["format"], r["format"]), str(r["frames"]),
             r.get("size", "-").replace("x", " x "),
             "skipped" if "skipped" in r else _num(r["write_s"], "s"),
             "-" if "skipped" in r else _num(r["bytes"] / 1e6, "MB")] for r in exports]
    head = ["format", "frames", "size", "write time", "file size"]
    lines = [_measured_on(data, source), "", *_table(head, rows)]
    drawn = next((r for r in exports if "render_s" in r), None)
    if drawn is not None:
        lines += ["", f"Drawing those {drawn['frames']} frames (a loop of single frames): "
                  f"{_num(drawn['render_s'], 's')}."]
    return "\n".join(lines)


def table1_table(data: dict, source: str) -> str:
    """`benchmarks/table1.py`: the paper's Table 1, `table1.format_table`."""
    meta = data.get("meta", {})
    return "\n".join([
        _measured_on(data, source, f"libigl {meta.get('libigl', '?')}",
                     f"{meta.get('iterations', '?')} iterations",
                     f"{meta.get('repeats', '?')} frames a measurement"),
        "", table1.format_table(data["rows"])])


def vmap_rules_table(data: dict, source: str) -> str:
    """`benchmarks/vmap_rules.py`: each kept second implementation against the plain vmap."""
    return _measured_on(data, source) + "\n\n" + vmap_rules.format_table(data)


def compile_table(data: dict, source: str) -> str:
    """`benchmarks/compile.py`: first calls, each in a fresh process, cold and cached."""
    return _measured_on(data, source) + "\n\n" + compile_times.format_table(data)


def animation_table(data: dict, source: str) -> str:
    """`benchmarks/animation.py`: an animation's frames from their turned starts, or each
    from the pose before."""
    return _measured_on(data, source) + "\n\n" + animation.format_table(data)


def jit_method_table(data: dict, source: str) -> str:
    """`benchmarks/jit_method.py`: the ways to jit a rig's frame."""
    return _measured_on(data, source) + "\n\n" + jit_method.format_table(data)


def many_rigs_table(data: dict, source: str) -> str:
    """`benchmarks/many_rigs.py`: memory as rigs of new sizes go by, and a new rig's time."""
    return _measured_on(data, source) + "\n\n" + many_rigs.format_table(data)


def stack_table(data: dict, source: str) -> str:
    """`benchmarks/stack.py`: glyphs posed and drawn as a stack, and in a loop."""
    return _measured_on(data, source) + "\n\n" + stack.format_table(data)


def dataset_table(data: dict, source: str) -> str:
    """`benchmarks/dataset.py`: posed pictures written per second."""
    return _measured_on(data, source) + "\n\n" + dataset.format_table(data)


def robustness_table(data: dict | None, source: str) -> str:
    """`benchmarks/robustness.py`: what happened to the hostile cases."""
    if data is None:
        return (f"No results yet: `python benchmarks/robustness.py --json {source}` writes "
                "them, and `python tools/tables.py` this table.")
    return f"From `{source}`.\n\n" + robustness.format_table(data["cases"])


# ---- pages ------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Table:
    page: str  # relative to the repository
    name: str  # the markers are <!-- {name}-table:start --> and <!-- {name}-table:end -->
    source: str  # the results file, relative to the repository
    format: Callable[[dict, str], str]
    optional: bool = False  # the results may not exist yet

    @property
    def start(self) -> str:
        return f"<!-- {self.name}-table:start -->"

    @property
    def end(self) -> str:
        return f"<!-- {self.name}-table:end -->"


def live_table(data: dict, source: str) -> str:
    """`benchmarks/live.py`: interact dragged with a real mouse, in a browser and a window."""
    rows = [[
        {"browser": "JupyterLab in Chromium (ipympl)", "window": "Tk window (Xvfb)"}[r["where"]],
        "textured" if r["textured"] else "filled", f"{r['shape_vertices']:,}",
        f"{r['moves']} every {r['step_s'] * 1e3:.0f} ms", str(r["updates"]),
        f"{r['drag_s']:.2f} s", f"{r['updates_per_s']:.1f}", _ms(r["update_ms"]),
        (f"{r['browser_pictures']} ({r['browser_pictures_per_s']:.1f} a second)"
         if r["where"] == "browser" else "-"),
        " / ".join(_ms(t) for t in r["pin_ms"]) if r.get("pin_ms") else "-",
    ] for r in data["rows"]]
    head = ["where", "drawn", "shape vertices", "mouse moves", "updates", "drag",
            "updates a second", "median update", "pictures the browser drew",
            "pin added / removed by a click, click to pose"]
    return "\n".join([_measured_on(data, source, "a real mouse"), "", *_table(head, rows)])


def _results(name: str) -> str:
    return f"{RESULTS}/{name}-cpu-2core.json"


BENCHMARKS = "docs/benchmarks.md"
TABLES = [
    Table("README.md", "folds-totals", _results("folds"),
          lambda data, _: folds.readme_table(data)),
    Table(BENCHMARKS, "deform", _results("deform"), deform_table),
    Table(BENCHMARKS, "solvers", _results("solvers"), solvers_table),
    Table(BENCHMARKS, "animation", _results("animation"), animation_table),
    Table(BENCHMARKS, "compile", _results("compile"), compile_table),
    Table(BENCHMARKS, "frames", _results("frames"), frames_table),
    Table(BENCHMARKS, "throughput-frame", _results("throughput"), throughput_frame_table),
    Table(BENCHMARKS, "throughput-batch", _results("throughput"), throughput_batch_table),
    Table(BENCHMARKS, "throughput-floors", _results("throughput"), throughput_floors_table),
    Table(BENCHMARKS, "many-rigs", _results("many_rigs"), many_rigs_table),
    Table(BENCHMARKS, "stack", _results("stack"), stack_table),
    Table(BENCHMARKS, "dataset", _results("dataset"), dataset_table),
    Table(BENCHMARKS, "interact", _results("interact"), interact_table),
    Table(BENCHMARKS, "live", _results("live"), live_table),
    Table(BENCHMARKS, "render", _results("render"), render_table),
    Table(BENCHMARKS, "render-peers", _results("render"), render_peers_table),
    Table(BENCHMARKS, "render-layers", _results("render"), render_layers_table),
    Table(BENCHMARKS, "render-export", _results("render"), render_export_table),
    Table("docs/paper.md", "table1", _results("table1"), table1_table),
    Table("docs/folds.md", "folds-summary", _results("folds"),
          lambda data, _: folds.summary_table(data)),
    Table("docs/folds.md", "folds", _results("folds"), lambda data, _: folds.format_tables(data)),
    Table("docs/robustness.md", "robustness", _results("robustness"), robustness_table,
          optional=True),
    Table("docs/guide.md", "jit-method", _results("jit_method"), jit_method_table),
    Table("docs/drawings.md", "drawings", _results("drawings"), drawings.format_table),
    Table("docs/drawings.md", "drawings-examples", _results("drawings_examples"),
          drawings.format_examples_table),
    Table("docs/how-it-works.md", "vmap-rules", _results("vmap_rules"), vmap_rules_table),
]


def body(table: Table, root: Path = ROOT) -> str:
    """What the results file of `table` gives for it."""
    path = root / table.source
    if not path.exists():
        if table.optional:
            return table.format(None, table.source)
        raise SystemExit(f"{table.source} is missing: {table.page}'s {table.name} table "
                         "has nothing to be written from.")
    with open(path) as f:
        return table.format(json.load(f), table.source)


def fill(text: str, table: Table, generated: str) -> str:
    """The page `text` with the section of `table` holding `generated`."""
    if table.name == "folds":  # written as `benchmarks/folds.py --table ... --docs ...` writes it
        return folds.fill_docs(text, generated, table.source, table.page)
    if text.count(table.start) != 1 or text.count(table.end) != 1:
        raise SystemExit(f"{table.page} needs exactly one {table.start} ... {table.end} "
                         "section for its table.")
    head, rest = text.split(table.start, 1)
    _, tail = rest.split(table.end, 1)
    note = ("<!-- Generated by `python tools/tables.py` from "
            f"{table.source}; do not edit by hand. -->")
    return f"{head}{table.start}\n{note}\n\n{generated}\n{table.end}{tail}"


def _section(text: str, table: Table) -> str | None:
    start = folds.DOCS_START if table.name == "folds" else table.start
    end = folds.DOCS_END if table.name == "folds" else table.end
    if text.count(start) != 1 or text.count(end) != 1:
        return None
    return text.split(start, 1)[1].split(end, 1)[0]


def pages(root: Path = ROOT, texts: dict[str, str] | None = None) -> dict[str, str]:
    """Every page with tables, as its tables' results give it (`texts`: the pages as
    they are, read from `root` where not given)."""
    texts = dict(texts or {})
    out = {}
    for table in TABLES:
        if table.page not in out:
            out[table.page] = texts.get(table.page) or (root / table.page).read_text()
        out[table.page] = fill(out[table.page], table, body(table, root))
    return out


def stale(root: Path = ROOT, texts: dict[str, str] | None = None) -> list[str]:
    """One line for each table whose page differs from what its results give (`texts`:
    the pages as they are, read from `root` where not given); empty when all agree."""
    texts = dict(texts or {})
    problems = []
    for table in TABLES:
        if table.page not in texts:
            texts[table.page] = (root / table.page).read_text()
        text = texts[table.page]
        current = _section(text, table)
        if current is None:
            problems.append(f"{table.page}: no section for the {table.name} table "
                            f"({table.start} ... {table.end})")
        elif current != _section(fill(text, table, body(table, root)), table):
            problems.append(f"{table.page}: the {table.name} table is stale (it differs "
                            f"from {table.source})")
    return problems


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="write nothing; exit 1, naming them, if tables are stale")
    args = parser.parse_args(argv)
    if args.check:
        problems = stale()
        for problem in problems:
            print(problem, file=sys.stderr)
        if problems:
            print("Regenerate them with `python tools/tables.py` (never edit a "
                  "generated table by hand).", file=sys.stderr)
            return 1
        print(f"{len(TABLES)} tables agree with {RESULTS}/")
        return 0
    for page, text in pages().items():
        if (ROOT / page).read_text() != text:
            (ROOT / page).write_text(text)
            print(f"wrote the tables of {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
