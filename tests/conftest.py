"""Shared problems. Tests run JAX as users do, in float32 (64-bit floats off); a test
that needs float64 (agreement with scipy or finite differences to many digits, the
solvers' internals) is marked `@pytest.mark.float64` (or its module is), and runs with
`jax_enable_x64` on. Turning it on is the tests' choice, never the library's.
"""

import collections
import contextlib
import os
import re

# The suite runs as two xdist workers on two cores (and notebooks in kernels of their
# own): one BLAS thread each, or OpenBLAS's spinning threads oversubscribe the machine
# and a scipy reference solve beside a notebook slows down many times over.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

# A program is compiled once per test run, not once per worker and per subprocess: the
# workers, the notebooks' kernels and the command lines the tests start share JAX's
# persistent compilation cache (set through the environment, so that the subprocesses
# inherit it). No size limit: with one, JAX locks the cache and scans every entry on
# each write, quadratic in the thousands of small programs a run writes; an entry read
# while another process writes it is a warning and a compile, not an error.
# `MVCJAX_TEST_JAX_CACHE=off` runs the suite without it, cold.
_CACHE = os.environ.get("MVCJAX_TEST_JAX_CACHE", os.path.join(
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".cache", "jax-tests"))
if _CACHE != "off":
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", _CACHE)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

# Most of the suite's time is XLA compiling programs that then run for milliseconds: the
# suite compiles them without LLVM's optimisations (`MVCJAX_TEST_XLA=optimised` keeps
# them), at a fraction of the CPU. The operations and their float semantics are
# the same; only the order of some roundings differs, as on another machine, and the
# verdicts that hang on rounding (convergence claimed, gradients against finite
# differences) are checked under both (`test_float32.py`).
UNOPTIMISED = "--xla_backend_optimization_level=0"
if os.environ.get("MVCJAX_TEST_XLA", "unoptimised") == "unoptimised" and (
        UNOPTIMISED not in os.environ.get("XLA_FLAGS", "")):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {UNOPTIMISED}".strip()

import jax  # noqa: E402
from hypothesis import settings  # noqa: E402

# Property tests: a few minutes at most by default; HYPOTHESIS_PROFILE=long for many more.
settings.register_profile("default", max_examples=12, derandomize=True)
settings.register_profile("long", max_examples=300)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import scipy.optimize  # noqa: E402

import mvcjax  # noqa: E402
from mvcjax import datasets  # noqa: E402


@pytest.fixture(scope="session")
def horse():
    return datasets.horse()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    # Fixtures are set up inside the protocol: a float64 test's fixtures are float64 too.
    # Set globally, not by `jax.enable_x64`'s context, which holds for this thread only:
    # host callbacks run on XLA's threads.
    jax.config.update("jax_enable_x64", item.get_closest_marker("float64") is not None)
    item.compiled_before = dict(_COMPILED)
    item.programs_before = (dict(_PROGRAM_SECONDS), dict(_PROGRAM_COUNT))
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)


# What each test compiles (XLA's compiles, or their loading from the persistent cache,
# and JAX's tracing), counted in its setup and call and sent with its report, even from
# an xdist worker: the run ends with the tests and the programs (by function name) that
# compile the most.
_COMPILE_EVENTS = {"/jax/core/compile/backend_compile_duration": "compile",
                   "/jax/core/compile/jaxpr_trace_duration": "trace"}
_COMPILED = collections.Counter()
_PROGRAM_SECONDS = collections.Counter()  # by function name: compile seconds
_PROGRAM_COUNT = collections.Counter()  # by function name: programs compiled


def _count_compiles(event, seconds, fun_name="?", **_):
    if event in _COMPILE_EVENTS:
        _COMPILED[_COMPILE_EVENTS[event] + "_s"] += seconds
        _COMPILED[_COMPILE_EVENTS[event] + "s"] += 1
        if _COMPILE_EVENTS[event] == "compile":
            _PROGRAM_SECONDS[fun_name] += seconds
            _PROGRAM_COUNT[fun_name] += 1


jax.monitoring.register_event_duration_secs_listener(_count_compiles)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    if call.when == "call" and hasattr(item, "compiled_before"):
        spent = _COMPILED - collections.Counter(item.compiled_before)
        item.user_properties.append(("compiled", {k: spent[k] for k in
                                                  ("compiles", "compile_s", "trace_s")}))
        item.user_properties.append(("programs", [
            dict(now - collections.Counter(before))
            for now, before in zip((_PROGRAM_SECONDS, _PROGRAM_COUNT), item.programs_before)]))
    yield


@contextlib.contextmanager
def float64_on():
    """64-bit floats on for a block of a float32 test (a float64 reference), set
    globally as the marker does."""
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", False)


def needs_float64(what: str) -> None:
    if not jax.config.jax_enable_x64:
        pytest.fail(f"{what} is float64: mark the test @pytest.mark.float64, or use a "
                    "float32 one.")


@pytest.fixture(scope="session")
def horse_rig(horse):
    """The horse's rig with the paper's energy in float64, for float64 tests of that
    energy and the solvers' internals (`test_arap.py` tests the default energy)."""
    needs_float64("horse_rig")
    return mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float64,
                            weights=mvcjax.Weights.paper())


@pytest.fixture(scope="session")
def horse_rig32(horse):
    """The horse's rig as users build it (float32)."""
    return mvcjax.Rig.build(horse, datasets.horse_handles(), dtype=jnp.float32)


@pytest.fixture(scope="session")
def ring_shape():
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    circle = np.stack([np.cos(t), np.sin(t)], axis=1)
    return mvcjax.Shape.from_polygon(50 * circle, [20 * circle[::-1]])


def drag(rig, offsets):
    """Targets: the handles' rest positions plus `offsets` (h, 2)."""
    return rig.handle_positions + jnp.asarray(offsets, rig.handle_positions.dtype)


def directional_derivatives(f, x, seed=0, h=1e-5):
    """`(grad f(x) . d, central finite difference along d)` for a random direction `d`."""
    d = jax.random.normal(jax.random.key(seed), x.shape, x.dtype)
    # Jitted: run eagerly, each operation of the solve and of its gradient would be a
    # program compiled of its own.
    exact = jnp.sum(jax.jit(jax.grad(f))(x) * d)
    f = jax.jit(f)
    approx = (f(x + h * d) - f(x - h * d)) / (2 * h)
    return float(exact), float(approx)


def _jaxprs_in(params) -> list:
    """The jaxprs among an equation's parameters (a loop's body, a branch, a program)."""
    found = []
    for value in params.values():
        for v in value if isinstance(value, (tuple, list)) else [value]:
            if isinstance(v, (jax.extend.core.Jaxpr, jax.extend.core.ClosedJaxpr)):
                found.append(getattr(v, "jaxpr", v))
    return found


def host_callbacks(jaxpr, inside: str) -> tuple[int, int]:
    """How many host callbacks `jaxpr` calls in all, and how many of them inside the
    programs named `inside`."""
    total = within = 0
    for e in jaxpr.eqns:
        total += "callback" in e.primitive.name
        for sub in _jaxprs_in(e.params):
            t, w = host_callbacks(sub, inside)
            total += t
            within += t if e.params.get("name") == inside else w
    return total, within


def scipy_minimum(rig, targets, start, method="trf"):
    """The energy's minimum near `start` by scipy.optimize.least_squares (an independent
    reference): control vertices `(c, 2)` and the energy there, in the user's units (the
    rig's energy is in its own frame)."""
    local_targets = rig.frame.to_local(rig.pinned_targets(targets))
    fun = jax.jit(lambda x: mvcjax.advanced.residuals(rig.energy, x.reshape(-1, 2), local_targets))
    jac = jax.jit(jax.jacfwd(fun))
    result = scipy.optimize.least_squares(
        lambda x: np.asarray(fun(x)), np.asarray(rig.frame.to_local(start)).ravel(),
        jac=lambda x: np.asarray(jac(x)),
        method=method, xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=5000,
    )
    scale = float(rig.frame.scale)
    return np.asarray(rig.frame.to_world(result.x.reshape(-1, 2))), 2 * result.cost * scale**2


def local_point(rig, offsets, noise=0.0, seed=0):
    """For tests of the solvers' internals, which work in the rig's frame: the local
    targets of a drag by `offsets` and the rigid start for them, perturbed by `noise`
    (in units of the rest diagonal)."""
    targets = drag(rig, offsets)
    start = rig.frame.to_local(rig.start(targets))
    start = start + noise * jax.random.normal(jax.random.key(seed), start.shape, start.dtype)
    return rig.frame.to_local(targets), start


# Exhaustive variants, run by `pytest -m slow` (CI runs them in a step of their own): the
# default suite keeps one or two of each family, and every test that only they would run.
SLOW = [
    # A character's pose fitted to its picture (compiling the fit through every part),
    # dragged with the mouse, and differentiated through its picture; its gradients
    # against finite differences stay in the default suite.
    "tests/test_character.py::test_fit_targets_finds_a_characters_pose_from_its_picture",
    "tests/test_character.py::test_interact_drags_a_character_and_records_it",
    "tests/test_character.py::test_gradients_flow_from_the_picture_to_the_targets",
    # Spare pins on a sparse factor (refactored on the host); the dense one stays.
    "tests/test_pins.py::test_spare_pins_change_nothing_until_placed_and_after_taken_out"
    "[sparse]",
    # Stacks solved by Gauss-Newton and FoldFree, and with a bone; FixedG on point
    # handles stays.
    "tests/test_stack.py::test_a_stack_poses_each_rig_as_it_poses_alone[*-GaussNewton]",
    "tests/test_stack.py::test_a_stack_poses_each_rig_as_it_poses_alone[*-FoldFree]",
    "tests/test_stack.py::test_a_stack_poses_each_rig_as_it_poses_alone[bone-FixedG]",
    # Running the notebooks (each in a kernel of its own, slow); that each matches
    # its script stays in the default suite.
    "tests/test_notebooks.py::test_notebook_runs[*]",
    # Each solver against scipy at one drag; the other two drags here.
    "tests/test_solvers.py::test_solvers_agree_with_scipy[*-0-offset1]",
    "tests/test_solvers.py::test_solvers_agree_with_scipy[*-4-offset2]",
    # Implicit gradients: Gauss-Newton and the implicit fixed-G kept.
    "tests/test_solvers.py::test_implicit_gradients_match_finite_differences_and_the_unrolled_one"
    "[levenberg_marquardt]",
    "tests/test_solvers.py::test_implicit_gradients_match_finite_differences_and_the_unrolled_one"
    "[dogleg]",
    "tests/test_solvers.py::test_implicit_gradients_match_finite_differences_and_the_unrolled_one"
    "[jaxopt_levenberg_marquardt]",
    "tests/test_solvers.py::test_implicit_gradients_match_finite_differences_and_the_unrolled_one"
    "[anderson_implicit]",
    "tests/test_solvers.py::test_energy_history_ends_where_the_solve_does[FixedG_anderson]",
    "tests/test_solvers.py::test_energy_history_ends_where_the_solve_does[Dogleg]",
    "tests/test_solvers.py::test_energy_history_ends_where_the_solve_does[JaxoptLevenbergMarquardt]",
    "tests/test_solvers.py::test_implicit_gradients_match_finite_differences_and_the_unrolled_one"
    "[fixed_g_implicit]",
    "tests/test_solvers.py::test_stop_early_differentiates_in_reverse_mode_either_way",
    "tests/test_solvers.py::test_jaxopt_does_not_warn_users",
    "tests/test_solvers.py::test_gradient_through_jaxopt_gauss_newton_where_it_converges",
    "tests/test_solver_options.py::test_forward_mode_through_a_solve_that_stops_early",
    "tests/test_solver_options.py::test_negative_tolerances_no_longer_fake_convergence[Dogleg]",
    "tests/test_solver_options.py::test_negative_tolerances_no_longer_fake_convergence"
    "[LevenbergMarquardt]",
    "tests/test_solver_options.py::test_an_overflowing_energy_is_not_converged[FixedG(i*",
    "tests/test_solver_options.py::test_an_overflowing_energy_is_not_converged[FixedG(a*",
    "tests/test_solver_options.py::test_an_overflowing_energy_is_not_converged[Dogleg()]",
    "tests/test_solver_options.py::test_an_overflowing_energy_is_not_converged[GaussNewton()]",
    "tests/test_solver_options.py::test_an_overflowing_energy_is_not_converged"
    "[JaxoptGaussNewton()]",
    # Structured descents against optimistix's at one damping; the other three here.
    "tests/test_descents.py::test_structured_descent_steps_are_optimistix_steps[*-10.0]",
    "tests/test_descents.py::test_structured_descent_steps_are_optimistix_steps[*-0.3]",
    "tests/test_descents.py::test_structured_descent_steps_are_optimistix_steps[*-0.001]",
    # Placements and scales: 1e3 and 1e-20 kept.
    "tests/test_robustness.py::test_any_placement_and_scale_in_float64[100000.0-1.0]",
    "tests/test_robustness.py::test_any_placement_and_scale_in_float64[1.0-0.001]",
    "tests/test_robustness.py::test_any_placement_and_scale_in_float64[0.0-1e+20]",
    "tests/test_robustness.py::test_any_placement_and_scale_in_float64[100000000.0-1.0]",
    "tests/test_descents.py::test_structured_descents_keep_float32",
    # A dataset written by two processes of one jax.distributed job (the same written by
    # two calls of one process stays).
    "tests/test_generate.py::test_two_processes_with_two_devices_each_write_the_dataset",
    # Many frames: sharded, through the sparse factor, and gradients (test_batching has
    # gradients through vmap).
    "tests/test_animation.py::test_frames_sharded_over_four_devices_give_the_same_result",
    "tests/test_animation.py::test_gradient_through_frames_matches_single_frames",
    "tests/test_animation.py::test_fixed_g_vmapped_steps_all_frames_as_plain_batching_would[sparse]",
    "tests/test_factor.py::test_gauss_newton_on_the_sparse_factor_over_frames",
    "tests/test_factor.py::test_gradient_through_the_sparse_solve",
    "tests/test_rig.py::test_structured_solvers_run_on_the_sparse_factor[GaussNewton]",
    # The jaxopt solvers against scipy (the optimistix and fixed-G ones stay), and a
    # batch of rigs under vmap (single rigs under vmap stay).
    "tests/test_solvers.py::test_solvers_agree_with_scipy[jaxopt_*-0-offset0]",
    "tests/test_batching.py::test_a_batch_of_rigs_falls_back_to_jax_batching",
    # The longest of the default run, each with a lighter sibling kept there: a character
    # warm-started frame after frame (a rig's stays, in test_animation), and dragged
    # fold-free in interact (a rig's stays); a laddered rig under FoldFree with a
    # bone (with points stays); the guide run as written (the README's stays); the memory
    # of sixteen rigs of new sizes (that rigs of one size share programs stays).
    "tests/test_character.py::test_warm_started_frames_start_each_from_the_pose_before",
    "tests/test_character.py::test_interact_poses_either_from_the_pose_before_with_fold_free"
    "[character]",
    "tests/test_ladder.py::test_a_laddered_rig_holds_and_returns_what_a_plain_rig_does"
    "[bone-FoldFree]",
    "tests/test_docs.py::test_the_page_runs_as_written[docs/guide.md]",
    "tests/test_programs.py::test_rigs_of_new_sizes_keep_no_programs_and_leave_the_users_compiled",
    # More of the longest, each a variant of a family whose other members stay in the
    # default run: a laddered rig under the least-squares and fold-free solvers (FixedG
    # with points and a bone, Gauss-Newton with a bone stay); a user's term on the
    # sparse factor (the dense stays); the kept vmap rules in float32 (float64's tighter
    # check stays); float32 at 1e-20 (1e20 stays); convergence claims with the Laplacian
    # alone (two other energies stay); FoldFree's frames warm-started (FixedG's stay);
    # the ARAP term mixed in a stack (alone stays); Dogleg on the sparse factor
    # (Levenberg-Marquardt stays); the default at 60 degrees (120 stays); the thin strip
    # (the spike stays); a character through the rig's protocol (the rig stays, and
    # test_character poses characters throughout); the front hooves apart against a
    # polygon offset plainly (test_close_parts' check of the same hooves stays).
    "tests/test_ladder.py::test_a_laddered_rig_holds_and_returns_what_a_plain_rig_does"
    "[points-FoldFree]",
    "tests/test_ladder.py::test_a_laddered_rig_holds_and_returns_what_a_plain_rig_does"
    "[points-GaussNewton]",
    "tests/test_energy.py::test_a_new_term_is_one_declaration[sparse]",
    "tests/test_batching.py::test_each_kept_rule_agrees_with_the_plain_vmap[float32-*]",
    "tests/test_solver_options.py::test_float32_shapes_at_the_ends_of_the_size_range_converge"
    "[1e-20]",
    "tests/test_float32.py::test_least_squares_solvers_claim_convergence_only_near_the_minimum"
    "[laplacian-only]",
    "tests/test_animation.py::test_warm_started_frames_start_each_from_the_pose_before"
    "[FoldFree]",
    "tests/test_arap.py::test_the_term_in_a_stack_and_a_ladder[mixed]",
    "tests/test_rig.py::test_structured_solvers_run_on_the_sparse_factor[Dogleg]",
    "tests/test_fold_free.py::test_the_default_reaches_the_minimum_of_a_raised_arm[60]",
    "tests/test_robustness.py::test_thin_shapes_build_in_seconds[strip 1e4 x 1]",
    "tests/test_character.py::test_a_rig_and_a_character_offer_one_protocol[character]",
    "tests/test_meshing.py::test_close_parts_move_independently",
    # Fitting to a picture in float32: a long compilation of its own; the default
    # suite fits in float64.
    "tests/test_fit.py::test_textured_fit_recovers_the_pose_in_float32",
    "tests/test_fit.py::test_a_rigid_bone_is_fitted_by_pivot_and_angle",
]


def pytest_collection_modifyitems(config, items):
    # A stale entry is a mistake, where its file was collected whole (no -k).
    files = set() if config.option.keyword else {item.nodeid.split("::")[0] for item in items}
    for pattern in SLOW:  # "*" is the only wildcard ("[" is literal, as in test ids)
        regex = re.compile(".*".join(map(re.escape, pattern.split("*"))) + "$")
        matched = [item for item in items if regex.match(item.nodeid)]
        if not matched and pattern.split("::")[0] in files:
            raise pytest.UsageError(f"conftest.SLOW: {pattern!r} matches no test; update it.")
        for item in matched:
            item.add_marker(pytest.mark.slow)


def pytest_terminal_summary(terminalreporter):
    # Float64 only where a test needs it: the share is printed with every run.
    ran = [report for outcome in ("passed", "failed")
           for report in terminalreporter.stats.get(outcome, []) if report.when == "call"]
    if ran:
        wide = sum("float64" in report.keywords for report in ran)
        terminalreporter.write_line(f"float64: {wide} of {len(ran)} tests run "
                                    f"({wide / len(ran):.0%})")
        compiled = sorted(((dict(report.user_properties).get("compiled", {}), report.nodeid)
                           for report in ran), key=lambda c: -c[0].get("compile_s", 0.0))
        total = collections.Counter()
        for counts, _ in compiled:
            total.update(counts)
        terminalreporter.write_line(
            f"compiled: {total['compiles']} XLA programs in {total['compile_s']:.0f} s, "
            f"traced in {total['trace_s']:.0f} s; the most:")
        for counts, nodeid in compiled[:10]:
            terminalreporter.write_line(
                f"  {counts.get('compile_s', 0.0):6.1f} s {counts.get('compiles', 0):4d} "
                f"programs (tracing {counts.get('trace_s', 0.0):5.1f} s)  {nodeid}")
        seconds, count = collections.Counter(), collections.Counter()
        for report in ran:
            spent, compiled_count = dict(report.user_properties).get("programs", ({}, {}))
            seconds.update(spent)
            count.update(compiled_count)
        terminalreporter.write_line("compiled, by function (all its sizes and options):")
        for name, spent in seconds.most_common(10):
            terminalreporter.write_line(f"  {spent:6.1f} s {count[name]:4d} programs  {name}")
