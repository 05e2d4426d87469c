"""The fold suite: poses that turn limbs far, curl a strip and bend letters, solved by every
solver, counting the triangles each turns inside out.

Poses, each at several angles (all of them functions of the rig's rest targets, so that
they do not depend on where the shape sits):

- character arm: the built-in character (`datasets.character()`, the paper-like sizes)
  with a `Bone` per arm (`datasets.character_bones("arms")`), the right arm's bone turned
  45 to 180 degrees about the shoulder (its end target moved, its start kept);
- character squash: the same rig, every target's height scaled by 0.75 and 0.5 about
  the lowest (the feet);
- character leg: a `Bone` per leg (`character_bones("legs")`), the right leg kicked out
  45 and 90 degrees about the hip;
- sprite: a figure drawn with Pillow at run time (`datasets.sprite()`: a `Bone` per
  limb, points on the chest and the toes): both arms raised overhead (150 and 170
  degrees), and the right arm alone raised 60, 90 and 150 degrees;
- horse: `datasets.horse()` with its hind hooves, back and head as points and a `Bone`
  from the right front knee to the hoof, the hoof curled back under the body 60 to 120
  degrees about the knee;
- snake: a strip 400 x 20 with round ends (`datasets.snake()`): points along its axis
  and a `Bone` at the head, curled into an arc of 90, 180 and 270 degrees, every target
  on the arc at its distance along the axis (`datasets.snake_curl`); snake-tapered, the
  same with its half width easing by 10% towards the ends (`snake(taper=0.1)`: no
  straight sides, which the control polygon would keep as one edge each);
- glyphs: the letters HKLTEFNMAR of DejaVu Sans at 200 pixels (`datasets.glyph`), pinned
  at 8%, 50% and 92% of their height on every stroke, two pins on a lone stroke
  (`datasets.glyph_handles`): the top
  pins turned 45 and 90 degrees about the middle pins' centre (a bend), and 90 degrees
  about their own centre (a twist); H also squashed to half its height.

For each pose and each solver: the flipped shape-mesh and control-mesh triangles, the
energy (and its ratio to the lowest any unconstrained solver found), the largest handle
miss (user units and percent of the rest diagonal), the steps and the time per frame.
The solvers:

- `default`: `rig.deform(targets)`, whatever the library's default is (its energy, the
  rig's default weights, is the one every solver below solves but the paper's two);
- `paper`: the paper's energy (`Weights.paper()`) by `FixedG()` from
  `init=mvcjax.advanced.RestStart()`, the paper's 15 iterations;
- `paper_default`: the paper's energy by `FixedG(iterations=100)` from the default start
  (mvcjax's default before the as-rigid-as-possible energy); the two paper rows solve
  another energy, so their energies are reported without a ratio to the lowest;
- the unconstrained solvers `GaussNewton()`, `Dogleg()`, `LevenbergMarquardt()` and
  `FixedG(anderson=5, iterations=300, stop_early=True)` ("anderson"), from the default
  start;
- `FoldFree()` (where mvcjax has it);
- `full`: the default energy solved on the shape mesh itself (`control=FullSolve()`, same
  shape spacing and bone samples: the same shape mesh, checked) by `GaussNewton()` (it
  converges in tens of steps; `FixedG(anderson=5, iterations=2000, stop_early=True)` is
  far slower there and stops short); its energy is on another mesh, reported but not
  compared with the control mesh's;
- `arap`: libigl's ARAP on the rig's shape mesh with the same pinned vertices and
  targets, `--arap-iterations` local-global steps (100 by default) from the full rig's
  default start (`full.start(targets)`); its energy is the full mesh's energy (6) at its
  result;
- `arap_control`: libigl's ARAP on the rig's control mesh, its pinned control vertices
  held at the pinned targets, as many steps from the rig's default start
  (`rig.start(targets)`), carried to the shape mesh by the rig's own skinning
  (`rig.skin`): what the control mesh and its skinning allow an ARAP energy.

The criterion (raise an arm without turning it inside out), recorded per pose:
where any unconstrained solver reaches a pose with no flipped shape triangle, the
default must reach one too (at most 2 flipped) with an energy within 2% of the lowest
the unconstrained solvers found (`default_ok`). And FoldFree's time per frame against
GaussNewton's (target: at most 3 times).

Times: every function compiled once per rig outside the timed region (compile times
recorded); the control-mesh solvers of a pose timed in turns (`interleaved_median_ms`),
so that their ratios come from one run; the full solve and ARAP timed apart (medians).

    python benchmarks/folds.py [--quick] [--json FILE]   # run, print the tables
    python benchmarks/folds.py --table FILE              # the markdown tables of a JSON
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from _peer import arap as igl_arap, igl_or_none, igl_version
from _timing import compile_ms, interleaved_median_ms, median_ms, spacing_for, write_results

UNCONSTRAINED = ("gauss_newton", "dogleg", "levenberg_marquardt", "anderson")
# The rows that solve the paper's energy (`Weights.paper()`), not the rig's default.
PAPER = ("paper", "paper_default")
CONTROL_SOLVERS = ("default", *PAPER, *UNCONSTRAINED, "fold_free")
LABELS = {
    "default": "default",
    "paper": "paper FixedG() rest",
    "paper_default": "paper FixedG(100)",
    "gauss_newton": "GaussNewton",
    "dogleg": "Dogleg",
    "levenberg_marquardt": "LM",
    "anderson": "Anderson",
    "fold_free": "FoldFree",
    "full": "full solve",
    "arap": "ARAP",
    "arap_control": "ARAP control",
}
QUICK_SOLVERS = ("default", *PAPER, "gauss_newton", "fold_free", "arap", "arap_control")
# Timed as users call them, `rig.deform(targets, ...)`, in a program of their own; the
# others (slower solvers) are timed with `return_info=True`, which adds the info's
# energy, fold count and handle miss (little against their solve): one compilation
# less each. `--quick` times every solver with its info.
TIMED_PLAIN = ("default", "paper")
GLYPHS = "HKLTEFNMAR"
# The criterion: at most this many flipped shape triangles, within this energy ratio.
MAX_FLIPPED, ENERGY_SLACK = 2, 1.02
FOLD_FREE_TARGET = 3.0  # FoldFree's time per frame over GaussNewton's
# Energies below this times the squared rest diagonal count as 0 (a pose at rest, to
# rounding): ratios of rounding errors would mean nothing.
ENERGY_FLOOR = 1e-8
QUICK_POSES = ("character-arm-90", "character-arm-180", "character-squash-0.5",
               "sprite-overhead-170", "glyph-K-bend-90")
FIGURE_POSES = ("character-arm-180", "sprite-arm-150", "sprite-overhead-170", "horse-curl-120",
                "snake-curl-270", "glyph-K-bend-90")


# ---- poses ------------------------------------------------------------------------------


def turn(point, centre, degrees: float) -> np.ndarray:
    """`point` turned `degrees` counter-clockwise about `centre`."""
    t = np.radians(degrees)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    centre = np.asarray(centre, np.float64)
    return centre + (np.asarray(point, np.float64) - centre) @ rot.T


def squash(rest: np.ndarray, factor: float) -> np.ndarray:
    """Every target's height scaled by `factor` about the lowest target's."""
    out = rest.copy()
    bottom = rest[:, 1].min()
    out[:, 1] = bottom + factor * (rest[:, 1] - bottom)
    return out


@dataclasses.dataclass
class Pose:
    """One pose: `targets(rest)` gives the `(t, 2)` targets from the rest ones."""

    key: str
    what: str
    angle: float
    targets: Callable[[np.ndarray], np.ndarray]


@dataclasses.dataclass
class Family:
    """One rig and the poses solved on it. `make()` returns `(shape, handles, options)`
    for `Rig.build` (`options` sets `shape_spacing` and perhaps `control`, a
    `PaperControl(spacing, margin)`)."""

    key: str
    make: Callable
    poses: list


def _turn_one(moved: int, about: int, degrees: float):
    """Targets with target `moved` turned `degrees` counter-clockwise about target
    `about`, the others at rest."""
    def targets(rest):
        t = rest.copy()
        t[moved] = turn(rest[moved], rest[about], degrees)
        return t
    return targets


def _arm(degrees):
    return _turn_one(5, 4, degrees)  # the right wrist about the right shoulder


def _kick(degrees):
    return _turn_one(7, 6, degrees)  # the right ankle about the right hip


def _overhead(degrees, both=True):
    def targets(rest):
        t = rest.copy()
        if both:
            t[2] = turn(rest[2], rest[1], -degrees)  # the left arm turns clockwise
        t[4] = turn(rest[4], rest[3], degrees)
        return t
    return targets


def _curl_leg(degrees):
    return _turn_one(5, 4, -degrees)  # the hoof back (clockwise) about the knee


def _bend(levels, degrees, twist=False):
    bottom, middle, top = (len(p) for p in levels)

    def targets(rest):
        t = rest.copy()
        tops = slice(bottom + middle, bottom + middle + top)
        centre = (rest[tops] if twist else rest[bottom:bottom + middle]).mean(axis=0)
        t[tops] = turn(rest[tops], centre, degrees)
        return t
    return targets


def families(quick: bool) -> list[Family]:
    """The suite's rigs and poses (`quick`: the poses of `QUICK_POSES`, on small meshes)."""
    from mvcjax import datasets

    size = 600 if quick else 1500  # shape-mesh vertices, about, where not the paper's

    def sized(shape, handles, **options):
        return shape, handles, {"shape_spacing": spacing_for(shape, size), **options}

    character = dict(datasets.model("character").options)
    out = [
        Family("character-arm",
               lambda: (datasets.character(), datasets.character_bones("arms"), character),
               [Pose(f"character-arm-{a}", f"character: right arm turned {a} deg about the "
                     "shoulder", a, _arm(a)) for a in (45, 90, 120, 150, 180)]
               + [Pose(f"character-squash-{f:g}", f"character: squashed to {f:g} of its height",
                       f, lambda r, f=f: squash(r, f)) for f in (0.75, 0.5)]),
        Family("character-leg",
               lambda: (datasets.character(), datasets.character_bones("legs"), character),
               [Pose(f"character-kick-{a}", f"character: right leg kicked {a} deg about the hip",
                     a, _kick(a)) for a in (45, 90)]),
        Family("sprite", lambda: sized(datasets.sprite(), datasets.sprite_handles()),
               [Pose(f"sprite-overhead-{a}", f"sprite: both arms raised {a} deg, overhead", a,
                     _overhead(a)) for a in (150, 170)]
               + [Pose(f"sprite-arm-{a}", f"sprite: right arm raised {a} deg", a,
                       _overhead(a, both=False)) for a in (60, 90, 150)]),
        Family("horse", lambda: sized(*_horse()),
               [Pose(f"horse-curl-{a}", f"horse: front hoof curled back {a} deg about the "
                     "knee", a, _curl_leg(a)) for a in (60, 90, 120)]),
        Family("snake", lambda: sized(datasets.snake(), datasets.snake_handles()),
               [Pose(f"snake-curl-{a}", f"snake: curled {a} deg", a,
                     lambda r, a=a: datasets.snake_curl(r, a)) for a in (90, 180, 270)]),
        # Its straight sides are one control edge each (see `datasets.snake`): the same
        # strip with a 10% taper tells the control polygon's part from the solvers'.
        Family("snake-tapered",
               lambda: sized(datasets.snake(taper=0.1), datasets.snake_handles()),
               [Pose(f"snake-tapered-curl-{a}", f"snake, tapered 10%: curled {a} deg", a,
                     lambda r, a=a: datasets.snake_curl(r, a)) for a in (90, 180, 270)]),
    ]
    for letter in GLYPHS:
        shape = datasets.glyph(letter)
        levels = datasets.glyph_handles(shape)
        poses = [Pose(f"glyph-{letter}-bend-{a}", f"glyph {letter}: top bent {a} deg about "
                      "the middle", a, _bend(levels, a)) for a in (45, 90)]
        poses.append(Pose(f"glyph-{letter}-twist-90", f"glyph {letter}: top twisted 90 deg",
                          90, _bend(levels, 90, twist=True)))
        if letter == "H":
            poses.append(Pose("glyph-H-squash-0.5", "glyph H: squashed to 0.5 of its height",
                              0.5, lambda r: squash(r, 0.5)))
        out.append(Family(f"glyph-{letter}",
                          lambda s=shape, lv=levels: sized(s, np.concatenate(lv)), poses))
    if quick:
        out = [dataclasses.replace(f, poses=[p for p in f.poses if p.key in QUICK_POSES])
               for f in out]
    return [f for f in out if f.poses]


def _horse():
    """The horse with its hind hooves, back and head as points and a bone from the right
    front knee to the hoof (target rows 4 and 5)."""
    import mvcjax
    from mvcjax import datasets

    h = datasets.horse_handles()
    knee, hoof = (268.5, 72.0), (272.0, 26.0)
    return datasets.horse(), [*map(tuple, h[1:]), mvcjax.Bone(knee, hoof)]


# ---- solving and measuring --------------------------------------------------------------


def control_solvers(names) -> dict:
    """`name -> (solver or None for the default, init or None for the default, weights
    or None for the rig's)` for the control-mesh solvers that this mvcjax has."""
    import mvcjax

    paper = mvcjax.Weights.paper()
    # The rest start; a string in an mvcjax before options were objects (a run before and
    # after a change).
    rest = getattr(mvcjax.advanced, "RestStart", lambda: "rest")()
    table = {
        "default": (None, None, None),
        "paper": (mvcjax.FixedG(), rest, paper),
        "paper_default": (mvcjax.FixedG(iterations=100), None, paper),
        "gauss_newton": (mvcjax.GaussNewton(), None, None),
        "dogleg": (mvcjax.Dogleg(), None, None),
        "levenberg_marquardt": (mvcjax.LevenbergMarquardt(), None, None),
        "anderson": (mvcjax.FixedG(anderson=5, iterations=300, stop_early=True), None, None),
    }
    fold_free = getattr(mvcjax, "FoldFree", None)
    if fold_free is not None:
        table["fold_free"] = (fold_free(), None, None)
    return {k: v for k, v in table.items() if k in names}


def _functions(rig, solver, init, plain: bool):
    """`(frame, result)`: `result` is the jitted `t -> (shape vertices, info)` of `rig`
    with this solver and start; `frame` the jitted `t -> shape vertices` (the frame a
    user times, without the info's energy, fold count and handle miss), or `result`
    itself if not `plain`."""
    import jax

    args = () if solver is None else (solver,)
    kw = {} if init is None else {"init": init}
    result = jax.jit(lambda t: rig.deform(t, *args, return_info=True, **kw))
    frame = jax.jit(lambda t: rig.deform(t, *args, **kw)) if plain else result
    return frame, result


def _flipped(rest, vertices, faces) -> int:
    import mvcjax

    return mvcjax.flipped_triangles(np.asarray(rest, np.float64),
                                    np.asarray(vertices, np.float64), np.asarray(faces))


def measure_family(family: Family, names, dtype, repeats: int, igl, arap_iterations: int,
                   figures, log, plain: bool = True) -> list[dict]:
    """The rows of every pose of `family`."""
    import jax
    import jax.numpy as jnp

    import mvcjax

    shape, handles, options = family.make()
    t0 = time.perf_counter()
    rig = mvcjax.Rig.build(shape, handles, dtype=dtype, **options)
    jax.block_until_ready(rig)
    build_s = time.perf_counter() - t0
    rest = np.asarray(rig.handle_positions, np.float64)
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(rig.shape_mesh.vertices), axis=0)))
    solvers = control_solvers(names)
    fns, compiles, errors = {}, {}, {}
    first = jnp.asarray(family.poses[0].targets(rest), dtype)
    for name, (solver, init, weights) in solvers.items():
        posed = rig if weights is None else rig.with_weights(weights)
        frame, result = _functions(posed, solver, init, plain and name in TIMED_PLAIN)
        try:
            compiles[name] = compile_ms(result, first)
            if frame is not result:
                compiles[name] = compile_ms(frame, first)
            fns[name] = (frame, result)
        except Exception as e:  # a solver still being written: recorded, not fatal
            errors[name] = f"{type(e).__name__}: {e}"
            log(f"  {name}: {errors[name]}")

    full = arap = arap_control = None
    if "arap_control" in names and igl is not None:
        _, arap_control = igl_arap(igl, rig.control_mesh, arap_iterations)
        control_start, skin = jax.jit(rig.start), jax.jit(rig.skin)
        control_pinned = jax.jit(rig.pinned_targets)
    if "full" in names or "arap" in names:
        # The same shape mesh: the same spacing, and bones pinned at the same points.
        spacing = getattr(options.get("control"), "spacing", None)
        t0 = time.perf_counter()
        full = mvcjax.Rig.build(shape, handles, control=mvcjax.FullSolve(spacing=spacing),
                                dtype=dtype, shape_spacing=options.get("shape_spacing"))
        jax.block_until_ready(full)
        full_build_s = time.perf_counter() - t0
        same = (np.array_equal(np.asarray(full.shape_mesh.faces), np.asarray(rig.shape_mesh.faces))
                and np.allclose(np.asarray(full.shape_mesh.vertices),
                                np.asarray(rig.shape_mesh.vertices)))
        if not same:
            raise RuntimeError(f"{family.key}: the full solve's shape mesh differs from the "
                               "rig's.")
        full_solver = mvcjax.GaussNewton()
        if "full" in names:
            full_frame = jax.jit(lambda t: full.deform(t, full_solver))
            full_solve = jax.jit(lambda t: full.solve(t, full_solver, return_info=True))
            compiles["full"] = compile_ms(full_frame, first)
            compile_ms(full_solve, first)
        if "arap" in names and igl is not None:
            arap_precompute_s, arap = igl_arap(igl, rig.shape_mesh, arap_iterations)
            full_start = jax.jit(full.start)
            full_energy = jax.jit(full.energy_at)
            pinned_targets = jax.jit(rig.pinned_targets)

    rows = []
    for pose in family.poses:
        targets = jnp.asarray(pose.targets(rest), dtype)
        row = {
            "pose": pose.key, "family": family.key, "what": pose.what, "angle": pose.angle,
            "V_S": int(rig.shape_mesh.vertices.shape[0]),
            "F_S": int(rig.shape_mesh.faces.shape[0]),
            "V_C": int(rig.control_mesh.vertices.shape[0]),
            "F_C": int(rig.control_mesh.faces.shape[0]),
            "handles": int(rest.shape[0]), "pinned": int(rig.control_mesh.handles.shape[0]),
            "diagonal": diagonal, "build_s": build_s, "solvers": {},
        }
        results = {}
        for name, (_, result) in fns.items():
            vertices, info = result(targets)
            vertices = np.asarray(vertices)
            results[name] = vertices
            row["solvers"][name] = {
                "flipped_shape": _flipped(rig.shape_mesh.vertices, vertices, rig.shape_mesh.faces),
                "flipped_control": int(info.inverted),
                "energy": float(info.energy),
                "handle_miss": float(info.handle_miss),
                "handle_miss_pct": 100.0 * float(info.handle_miss) / diagonal,
                "iterations": int(info.iterations),
                "converged": bool(info.converged),
                "compile_ms": compiles[name],
            }
        times = interleaved_median_ms(
            {name: (frame, [(targets,)]) for name, (frame, _) in fns.items()}, repeats,
            budget_s=10.0 if repeats > 10 else 3.0)
        for name, ms in times.items():
            row["solvers"][name]["frame_ms"] = ms
        for name, error in errors.items():
            row["solvers"][name] = {"error": error}
        if full is not None and "full" in names:
            vertices, info = full_solve(targets)
            vertices = np.asarray(vertices)
            results["full"] = vertices
            row["solvers"]["full"] = {
                "solver": "GaussNewton()",
                "flipped_shape": _flipped(rig.shape_mesh.vertices, vertices,
                                          rig.shape_mesh.faces),
                "flipped_control": None, "energy": float(info.energy),
                "handle_miss": float(info.handle_miss),
                "handle_miss_pct": 100.0 * float(info.handle_miss) / diagonal,
                "iterations": int(info.iterations), "converged": bool(info.converged),
                "compile_ms": compiles["full"], "build_s": full_build_s,
                "frame_ms": median_ms(full_frame, [(targets,)], 3),
            }
        if arap is not None:
            pinned = np.asarray(pinned_targets(targets), np.float64)
            start = np.asarray(full_start(targets), np.float64)
            vertices = arap(pinned, start)
            results["arap"] = vertices
            miss = float(np.linalg.norm(vertices[np.asarray(rig.shape_mesh.handles)] - pinned,
                                        axis=1).max())
            row["solvers"]["arap"] = {
                "iterations": arap_iterations,
                "flipped_shape": _flipped(rig.shape_mesh.vertices, vertices,
                                          rig.shape_mesh.faces),
                "flipped_control": None,
                "energy": float(full_energy(jnp.asarray(vertices, dtype), targets)),
                "handle_miss": miss, "handle_miss_pct": 100.0 * miss / diagonal,
                "precompute_s": arap_precompute_s,
                "frame_ms": median_ms(arap, [(pinned, start)], 3),
            }
        if arap_control is not None:
            row["solvers"]["arap_control"] = _control_arap_row(
                rig, arap_control, skin, np.asarray(control_pinned(targets), np.float64),
                np.asarray(control_start(targets), np.float64), arap_iterations, diagonal)
        summarise(row)
        rows.append(row)
        log(_line(row))
        if figures is not None and pose.key in FIGURE_POSES:
            path = figures / f"folds-{pose.key}.png"
            figure(rig, results, row, path, np.asarray(rig.pinned_targets(targets)))
            row["figure"] = str(path)
    return rows


def _control_arap_row(rig, arap, skin, pinned, start, iterations: int, diagonal: float
                      ) -> dict:
    """The row of libigl's ARAP on the control mesh, skinned to the shape mesh."""
    control = arap(pinned, start)
    vertices = np.asarray(skin(control.astype(np.asarray(start).dtype)))
    handles = np.asarray(rig.control_mesh.handles)
    miss = float(np.linalg.norm(control[handles] - pinned, axis=1).max())

    def frame(p, s):
        return skin(arap(p, s).astype(s.dtype)).block_until_ready()

    return {
        "iterations": iterations,
        "flipped_shape": _flipped(rig.shape_mesh.vertices, vertices, rig.shape_mesh.faces),
        "flipped_control": _flipped(rig.control_mesh.vertices, control, rig.control_mesh.faces),
        "handle_miss": miss, "handle_miss_pct": 100.0 * miss / diagonal,
        "frame_ms": median_ms(frame, [(pinned, start.astype(np.float32))], 3),
    }


def summarise(row: dict) -> None:
    """The criterion's fields of a pose's row, from its solvers' results."""
    s = row["solvers"]
    ran = [k for k in UNCONSTRAINED if "energy" in s.get(k, {})]
    row["unconstrained"] = ran
    if ran:
        lowest = min(ran, key=lambda k: s[k]["energy"])
        row["lowest_energy"], row["lowest_by"] = s[lowest]["energy"], lowest
        unfolded = [k for k in ran if s[k]["flipped_shape"] == 0]
        row["unfolded_by"] = unfolded
        row["any_unfolded"] = bool(unfolded)
        row["lowest_unfolded_energy"] = (min(s[k]["energy"] for k in unfolded)
                                         if unfolded else None)
        floor = ENERGY_FLOOR * row["diagonal"] ** 2
        for k in CONTROL_SOLVERS:
            # The paper's rows minimise another energy: no ratio to the lowest.
            if "energy" in s.get(k, {}) and k not in PAPER:
                s[k]["energy_ratio"] = (max(s[k]["energy"], floor)
                                        / max(row["lowest_energy"], floor))
    d = s.get("default", {})
    if ran and "energy" in d:
        row["default_flipped"] = d["flipped_shape"]
        row["default_energy_ratio"] = d["energy_ratio"]
        row["default_reaches"] = bool(d["flipped_shape"] <= MAX_FLIPPED
                                      and d["energy_ratio"] <= ENERGY_SLACK)
        row["default_ok"] = bool(not row["any_unfolded"] or row["default_reaches"])
        if row["lowest_unfolded_energy"] is not None:
            row["default_energy_ratio_unfolded"] = (
                max(d["energy"], floor) / max(row["lowest_unfolded_energy"], floor))
    ff, gn = s.get("fold_free", {}), s.get("gauss_newton", {})
    if "frame_ms" in ff and "frame_ms" in gn:
        row["fold_free_gn_time_ratio"] = ff["frame_ms"] / gn["frame_ms"]
        row["fold_free_within_target"] = row["fold_free_gn_time_ratio"] <= FOLD_FREE_TARGET


def _line(row) -> str:
    s = row["solvers"]
    parts = [f"{LABELS[k]} {v['flipped_shape']}/{_fmt(v.get('flipped_control'), 'd')} "
             f"E{_fmt(v.get('energy_ratio'), '.3f')} {v['frame_ms']:.2f}ms"
             for k, v in s.items() if "flipped_shape" in v]
    ok = row.get("default_ok")
    return f"  {row['pose']}: " + "; ".join(parts) + f"; default_ok={ok}"


# ---- figures ----------------------------------------------------------------------------


def figure(rig, results: dict, row: dict, path: Path, pinned=None) -> None:
    """Rest, default, GaussNewton and FoldFree side by side: the shape meshes, flipped
    triangles in red, the pinned points' targets (`pinned`, `(r, 2)`) as black dots."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    rest = np.asarray(rig.shape_mesh.vertices, np.float64)
    faces = np.asarray(rig.shape_mesh.faces)
    panels = [("rest", rest, None)]
    for name in ("paper_default", "default", "fold_free"):
        if name in results:
            panels.append((LABELS[name], np.asarray(results[name], np.float64),
                           row["solvers"][name]))

    def signed(v):
        a, b, c = (v[faces[:, k]] for k in range(3))
        return (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]

    every = np.concatenate([p[1] for p in panels] + ([] if pinned is None else [pinned]))
    lo, hi = every.min(axis=0), every.max(axis=0)
    pad = 0.04 * (hi - lo).max()
    width = float(np.clip(3.6 * (hi - lo)[0] / (hi - lo)[1], 2.4, 6.0))
    fig, axes = plt.subplots(1, len(panels), figsize=(width * len(panels), 3.8))
    for ax, (title, v, result) in zip(np.atleast_1d(axes), panels):
        flipped = np.sign(signed(v)) != np.sign(signed(rest))
        colours = np.where(flipped[:, None], [[0.85, 0.1, 0.1, 1.0]], [[0.75, 0.82, 0.92, 1.0]])
        ax.add_collection(PolyCollection(v[faces], facecolors=colours,
                                         edgecolors=(0.3, 0.4, 0.6, 0.5), linewidths=0.1))
        if result is not None:
            title += (f"\n{result['flipped_shape']} flipped, E/min "
                      f"{_fmt(result.get('energy_ratio'), '.3f')}")
        if result is not None and pinned is not None:
            ax.plot(*np.asarray(pinned).T, "k.", ms=2.5)
        ax.set_title(title, fontsize=9)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(row["what"], fontsize=10, y=1.04)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)


# ---- tables -----------------------------------------------------------------------------


def _fmt(value, spec) -> str:
    return "-" if value is None else format(value, spec)


def _cell(s: dict, key: str, spec: str) -> str:
    if "error" in s:
        return "error"
    return _fmt(s.get(key), spec)


def suite_totals(rows: list[dict], name: str) -> dict | None:
    """A solver's totals over the suite's poses: flipped shape triangles, the poses with
    any, and the median and largest time per frame and first compile (ms)."""
    ran = [r["solvers"][name] for r in rows if "flipped_shape" in r["solvers"].get(name, {})]
    if not ran:
        return None
    times = [s["frame_ms"] for s in ran if s.get("frame_ms") is not None]
    compiles = [s["compile_ms"] for s in ran if s.get("compile_ms") is not None]
    return {
        "poses": len(ran),
        "flipped": sum(s["flipped_shape"] for s in ran),
        "folded_poses": sum(s["flipped_shape"] > 0 for s in ran),
        "median_ms": float(np.median(times)) if times else None,
        "max_ms": max(times) if times else None,
        "compile_median_ms": float(np.median(compiles)) if compiles else None,
    }


def _present(rows: list[dict]) -> list[str]:
    """The solvers that ran, in the tables' order."""
    return [k for k in (*CONTROL_SOLVERS, "full", "arap", "arap_control")
            if any(k in r["solvers"] for r in rows)]


def summary_table(data: dict) -> str:
    """The suite's totals, a row per solver (`docs/folds.md`'s first table)."""
    return "\n".join(totals_table(data["rows"], _present(data["rows"])))


def totals_table(rows: list[dict], present) -> list[str]:
    """The suite's totals, a row per solver (`suite_totals`)."""
    out = ["**The suite's totals**: flipped shape triangles summed over the poses, the poses "
           "with any, and the time per frame (median and largest over the poses) and the "
           "first call's compile (median), in ms:", "",
           "| solver | poses | flipped | poses folded | median frame | max frame | "
           "median compile |", "|---|---|---|---|---|---|---|"]
    for k in present:
        t = suite_totals(rows, k)
        if t is not None:
            out.append(f"| {LABELS[k]} | {t['poses']} | {t['flipped']} | {t['folded_poses']} | "
                       f"{_fmt(t['median_ms'], '.3g')} | {_fmt(t['max_ms'], '.3g')} | "
                       f"{_fmt(t['compile_median_ms'], '.3g')} |")
    return out + [""]


def readme_table(data: dict) -> str:
    """The README's lines on the default energy: the suite's totals for the default and
    the paper's energy, FoldFree and libigl's ARAP."""
    rows = data["rows"]
    names = [k for k in ("default", "paper_default", "paper", "fold_free", "arap_control",
                         "arap") if suite_totals(rows, k) is not None]
    what = {
        "default": "`rig.deform(targets)`: the as-rigid-as-possible energy (default)",
        "paper_default": "the paper's energy, `Weights.paper()`, 100 fixed-G steps",
        "paper": "the paper's energy and method, `FixedG()` from rest",
        "fold_free": "`FoldFree()` (never folds)",
        "arap_control": "libigl's ARAP on the same control mesh",
        "arap": "libigl's ARAP on the whole shape mesh",
    }
    out = [f"| on the fold suite ({len(rows)} poses, {data.get('meta', {}).get('dtype', '?')}) "
           "| flipped triangles | poses with a fold | median frame (ms) |", "|---|---|---|---|"]
    for k in names:
        t = suite_totals(rows, k)
        out.append(f"| {what[k]} | {t['flipped']} | {t['folded_poses']} | "
                   f"{_fmt(t['median_ms'], '.2g')} |")
    return "\n".join(out) + "\n"


def format_tables(data: dict) -> str:
    """The markdown tables of a results JSON (`data` as loaded): the criterion, the flips,
    the energies and handle misses, the times."""
    rows = data["rows"]
    meta = data.get("meta", {})
    runs = meta.get("runs", 1)
    present = _present(rows)
    out = []
    out.append(
        f"Measured on {meta.get('cpu_count', '?')} cores ({meta.get('device', '?')}), JAX "
        f"{meta.get('jax', '?')}, {meta.get('dtype', '?')}, libigl {meta.get('libigl', '?')}"
        f"{', quick run' if meta.get('quick') else ''}"
        f"{f', in {runs} runs (--resume)' if runs > 1 else ''}"
        f"{', on different mvcjax sources' if len(meta.get('mvcjax_sources', [])) > 1 else ''}"
        f"{'; INCOMPLETE: the run was cut short' if meta.get('complete') is False else ''}."
        + (f" The default, `rig.deform(targets)`, ran `{meta['default_solver']}` from "
           f"init={meta['default_init']}." if "default_solver" in meta else ""))
    out.append("")
    out.append("**The criterion.** Unfolded: the unconstrained solvers that reached 0 flipped "
               "shape triangles. Lowest: the lowest energy of the unconstrained solvers "
               "(which). Default: flipped shape / control triangles, its energy over the "
               f"lowest; ok: no unconstrained solver unfolded it, or the default has at "
               f"most {MAX_FLIPPED} flipped with an energy within "
               f"{round((ENERGY_SLACK - 1) * 100)}%. FoldFree: flipped, energy over the "
               "lowest, largest handle miss (% of the diagonal), time over GaussNewton's "
               f"(target at most {FOLD_FREE_TARGET:g}).")
    out.append("")
    head = ["pose", "V_S / V_C", "unfolded", "lowest (by)", "default flipped", "default E / lowest",
            "default ok", "FoldFree flipped", "FoldFree E / lowest", "FoldFree miss",
            "FoldFree / GN time"]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        s = r["solvers"]
        d, ff = s.get("default", {}), s.get("fold_free", {})
        unfolded = ", ".join(LABELS[k] for k in r.get("unfolded_by", [])) or "none"
        ok = r.get("default_ok")
        out.append("| " + " | ".join([
            r["pose"], f"{r['V_S']} / {r['V_C']}", unfolded,
            f"{_fmt(r.get('lowest_energy'), '.4g')} ({LABELS.get(r.get('lowest_by'), '-')})",
            f"{_cell(d, 'flipped_shape', 'd')} / {_cell(d, 'flipped_control', 'd')}",
            _cell(d, "energy_ratio", ".3f"),
            "-" if ok is None else ("yes" if ok else "**no**"),
            f"{_cell(ff, 'flipped_shape', 'd')} / {_cell(ff, 'flipped_control', 'd')}"
            if ff else "-",
            _cell(ff, "energy_ratio", ".3f") if ff else "-",
            (_cell(ff, "handle_miss_pct", ".2f") + "%") if "handle_miss_pct" in ff else "-",
            _fmt(r.get("fold_free_gn_time_ratio"), ".2f"),
        ]) + " |")
    out.append("")
    ok = [r.get("default_ok") for r in rows if r.get("default_ok") is not None]
    ratios = [r["fold_free_gn_time_ratio"] for r in rows if "fold_free_gn_time_ratio" in r]
    out.append(f"Default ok on {sum(ok)} of {len(ok)} poses"
               + (f"; FoldFree / GaussNewton time from {min(ratios):.2f} to {max(ratios):.2f}, "
                  f"within {FOLD_FREE_TARGET:g} on {sum(x <= FOLD_FREE_TARGET for x in ratios)} "
                  f"of {len(ratios)}." if ratios else "."))
    out.append("")

    def table(title, cell):
        lines = [title, "", "| pose | " + " | ".join(LABELS[k] for k in present) + " |",
                 "|---|" + "---|" * len(present)]
        for r in rows:
            lines.append(f"| {r['pose']} | " + " | ".join(
                cell(r["solvers"].get(k, {}), k) if k in r["solvers"] else "-"
                for k in present) + " |")
        return lines + [""]

    out += table(
        "**Flipped triangles**, shape mesh / control mesh (the full solve and ARAP have the "
        "shape mesh only):",
        lambda s, k: "error" if "error" in s else (
            f"{s['flipped_shape']}" + ("" if s.get("flipped_control") is None
                                       else f" / {s['flipped_control']}")))
    out += table(
        "**Energy** over the lowest of the unconstrained solvers (control mesh); the full "
        "solve's and ARAP's energies are on the shape mesh (the same energy (6) there), so "
        "they are given as numbers, not ratios:",
        lambda s, k: "error" if "error" in s else (
            _fmt(s.get("energy"), ".4g") if k in ("full", "arap")
            else _fmt(s.get("energy_ratio"), ".3f")))
    out += table(
        "**Largest handle miss**, percent of the rest bounding-box diagonal:",
        lambda s, k: _cell(s, "handle_miss_pct", ".3f"))
    out += table(
        "**Time per frame**, ms (median; the control-mesh solvers timed in turns; steps in "
        "brackets):",
        lambda s, k: "error" if "error" in s else (
            f"{_fmt(s.get('frame_ms'), '.3g')}"
            + (f" ({s['iterations']})" if "iterations" in s and k != "arap" else "")))
    return "\n".join(out).rstrip() + "\n"


def source_hash() -> str:
    """SHA-1 of the sources of the mvcjax that is imported (every .py file under it)."""
    import hashlib

    import mvcjax

    digest = hashlib.sha1()
    root = Path(mvcjax.__file__).parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:12]


DOCS_START, DOCS_END = "<!-- folds-table:start -->", "<!-- folds-table:end -->"


def fill_docs(text: str, tables: str, source: str, path: str) -> str:
    """The page `text` (at `path`) with the lines between `DOCS_START` and `DOCS_END`
    replaced by `tables` (generated from the results file `source`)."""
    if DOCS_START not in text or DOCS_END not in text:
        raise SystemExit(f"{path} has no {DOCS_START} ... {DOCS_END} section to fill.")
    head, rest = text.split(DOCS_START, 1)
    _, tail = rest.split(DOCS_END, 1)
    note = (f"<!-- Generated by `python benchmarks/folds.py --table {source} --docs {path}`; "
            "do not edit by hand. -->")
    return f"{head}{DOCS_START}\n{note}\n\n{tables}\n{DOCS_END}{tail}"


def write_docs(path: str, tables: str, source: str) -> None:
    """The page at `path` with its tables section filled by `fill_docs`."""
    Path(path).write_text(fill_docs(Path(path).read_text(), tables, source, path))
    print(f"wrote the tables of {source} into {path}")


# ---- main -------------------------------------------------------------------------------


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="a handful of poses, the cheap solvers, small meshes")
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--table", metavar="JSON",
                        help="print the markdown tables of this results file and stop")
    parser.add_argument("--docs", metavar="MARKDOWN",
                        help="with --table: write the tables into this page, between its "
                        f"lines {DOCS_START!r} and {DOCS_END!r}, instead of printing them")
    parser.add_argument("--only", nargs="*", help="only the families with these keys")
    parser.add_argument("--resume", action="store_true",
                        help="with --json: keep the families already in that file (a run "
                        "cut short), measure the others")
    parser.add_argument("--repeats", type=int, help="timed frames per solver and pose")
    parser.add_argument("--arap-iterations", type=int, default=100)
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    parser.add_argument("--figures", help="folder for the figures ('' for none; default "
                        "benchmarks/results/figures, none with --quick)")
    args = parser.parse_args(argv)
    if args.table:
        import json

        with open(args.table) as f:
            tables = format_tables(json.load(f))
        if args.docs:
            write_docs(args.docs, tables, args.table)
        else:
            print(tables, end="")
        return 0

    import jax

    if args.dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp

    dtype = jnp.dtype(args.dtype)
    repeats = args.repeats or (8 if args.quick else 20)
    figures = args.figures if args.figures is not None else (
        "" if args.quick else "benchmarks/results/figures")
    figures = Path(figures) if figures else None
    names = QUICK_SOLVERS if args.quick else (*CONTROL_SOLVERS, "full", "arap", "arap_control")
    igl = igl_or_none()
    if igl is None:
        print("libigl is missing: the ARAP columns are skipped. Install it with "
              "pip install 'mvcjax[bench]' (or pip install libigl).", flush=True)
    import mvcjax

    if getattr(mvcjax, "FoldFree", None) is None:
        print("mvcjax has no FoldFree: its columns are skipped.", flush=True)

    def log(text):
        print(text, flush=True)

    import inspect

    deform = inspect.signature(mvcjax.Rig.deform).parameters
    meta = dict(benchmark="folds", quick=args.quick, dtype=args.dtype, repeats=repeats,
                default_solver=repr(deform["solver"].default),
                default_init=repr(deform["init"].default), full_solver="GaussNewton()",
                arap_iterations=args.arap_iterations, libigl=igl_version(igl),
                solvers={k: LABELS[k] for k in names},
                timed_plain=[] if args.quick else list(TIMED_PLAIN),
                criterion=dict(max_flipped=MAX_FLIPPED, energy_slack=ENERGY_SLACK,
                               energy_floor=ENERGY_FLOOR,
                               fold_free_target=FOLD_FREE_TARGET, unconstrained=UNCONSTRAINED))
    # What was measured: a hash of mvcjax's sources as this run imported them (a run
    # resumed on other sources would mix two versions: their hashes are all kept).
    meta["mvcjax_sources"] = [source_hash()]
    rows, seconds, runs = [], 0.0, 1
    if args.resume and args.json and Path(args.json).exists():
        import json

        with open(args.json) as f:
            done = json.load(f)
        rows, seconds = done["rows"], done["meta"].get("seconds", 0.0)
        runs = done["meta"].get("runs", 1) + 1
        before = done["meta"].get("mvcjax_sources", [])
        meta["mvcjax_sources"] = list(dict.fromkeys([*before, *meta["mvcjax_sources"]]))
        print(f"resuming {args.json}: {len({r['family'] for r in rows})} families done"
              + ("" if before == meta["mvcjax_sources"] else
                 "; mvcjax's sources changed since: the results mix two versions"), flush=True)
    start = time.perf_counter()
    families_done = {r["family"] for r in rows}
    chosen = [f for f in families(args.quick) if not args.only or f.key in args.only]
    for family in chosen:
        if family.key in families_done:
            continue
        log(f"{family.key} ({time.perf_counter() - start:.0f} s)")
        rows += measure_family(family, names, dtype, repeats, igl, args.arap_iterations,
                               figures, log, plain=not args.quick)
        if args.json:  # after every family: a run cut short keeps what it measured
            complete = family is chosen[-1]
            write_results(args.json, rows, **meta, complete=complete, runs=runs,
                          seconds=seconds + time.perf_counter() - start)
    print()
    print(format_tables({"meta": {**meta, "device": jax.devices()[0].device_kind,
                                  "jax": jax.__version__,
                                  "cpu_count": __import__("os").cpu_count()},
                         "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
