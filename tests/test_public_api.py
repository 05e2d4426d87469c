"""The public face: what `import mvcjax` offers (`__all__`, at most 35 names), what moved
to `mvcjax.advanced`, and docs/api.md documenting every public name of both."""

import os
import re
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import mvcjax

API = (Path(__file__).resolve().parent.parent / "docs" / "api.md").read_text()
# The pipeline's stages: packages a script may import from, not names of the top level.
STAGES = {"core", "geometry", "energy", "solvers", "rig", "rendering", "character", "plot"}


def public(module) -> set[str]:
    # `jaxtyping`: put there by the test run's runtime type checks (pyproject's addopts).
    return {name for name in vars(module) if not name.startswith("_")} - {"jaxtyping"}


def test_the_top_level_is_all_and_small():
    assert len(mvcjax.__all__) <= 35
    assert sorted(set(mvcjax.__all__)) == sorted(mvcjax.__all__)
    assert sorted(dir(mvcjax)) == sorted(mvcjax.__all__)
    for name in mvcjax.__all__:  # each loaded on first use (__init__.pyi)
        getattr(mvcjax, name)
    assert public(mvcjax) - STAGES - {"lazy_loader"} == set(mvcjax.__all__)


def test_import_mvcjax_and_help_load_no_jax(tmp_path):
    # `import mvcjax`, `mvcjax --help` and a command refused for a missing file answer at
    # once (the command line's compilation cache set up without loading JAX); JAX comes
    # with the first name used.
    script = ("import sys, mvcjax, mvcjax.__main__ as cli\n"
              "assert 'jaxlib' not in sys.modules, 'import'\n"
              "try:\n    cli.main(['animate', '--help'])\nexcept SystemExit:\n    pass\n"
              "assert 'jaxlib' not in sys.modules, 'help'\n"
              "assert cli.main(['animate', 'missing.yaml', 'out.gif']) != 0\n"
              "assert 'jaxlib' not in sys.modules, 'refused'\n"
              "mvcjax.Weights\nassert 'jaxlib' in sys.modules\n")
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True,
                   env={**env, "MVCJAX_COMPILE_CACHE": str(tmp_path)}, cwd=tmp_path)


def test_every_public_name_is_in_the_api_reference():
    documented = set(re.findall(r"^::: (mvcjax\.[\w.]+)$", API, flags=re.M))
    names = [f"mvcjax.{n}" for n in mvcjax.__all__
             if not isinstance(getattr(mvcjax, n), types.ModuleType)]
    names += [f"mvcjax.advanced.{n}" for n in public(mvcjax.advanced)
              if not isinstance(getattr(mvcjax.advanced, n), types.ModuleType)]
    assert sorted(set(names) - documented) == []


@pytest.mark.parametrize("name", ["MVCSkinning", "SolveInfo", "FitResult", "Layer",
                                  "JaxoptGaussNewton", "SparseLU", "Energy"])
def test_a_name_moved_to_advanced_says_where_it_is(name):
    with pytest.raises(AttributeError, match=rf"mvcjax.advanced.{name}"):
        getattr(mvcjax, name)
    assert getattr(mvcjax.advanced, name) is not None


@pytest.fixture(scope="module")
def square():
    """A small rig, its renderer, its rest targets and an opaque picture."""
    shape = mvcjax.Shape.from_polygon([(0, 0), (40, 0), (40, 40), (0, 40)])
    rig = mvcjax.Rig.build(shape, [(5, 5), (35, 35)])
    renderer = mvcjax.Renderer.build(rig, size=(24, 24))
    picture = np.ones((24, 24, 4))  # opaque: a dark square on white
    picture[6:18, 6:18, :3] = 0.2
    return rig, renderer, rig.handle_positions, picture


# Each option that was once a string: a call taking the option's value, the old string,
# the object to write instead.
OLD_STRINGS = {
    "init-turned": (lambda r, d, t, p, o: r.deform(t, init=o), "turned", "TurnedStart"),
    "init-rigid": (lambda r, d, t, p, o: r.solve(t, init=o), "rigid", "RigidStart"),
    "init-rest": (lambda r, d, t, p, o: r.start(t, init=o), "rest", "RestStart"),
    "window": (lambda r, d, t, p, o: d(r.deform(t), window=o), "grow", "GrownWindow"),
    "fill": (lambda r, d, t, p, o: mvcjax.Renderer.build(r, fill=o), "checkerboard",
             "Checkerboard"),
    "alpha-mesh": (lambda r, d, t, p, o: mvcjax.Renderer.build(r, alpha=o), "mesh",
                   "MeshAlpha"),
    "alpha-picture": (lambda r, d, t, p, o: mvcjax.Renderer.build(r, alpha=o), "picture",
                      "PictureAlpha"),
    "channels-rgba": (lambda r, d, t, p, o: mvcjax.image_loss(r, d, t, p, channels=o), "rgba",
                      "RGBAChannels"),
    "channels-alpha": (lambda r, d, t, p, o: mvcjax.image_loss(r, d, t, p, channels=o),
                       "alpha", "AlphaChannel"),
    "background-mask": (lambda r, d, t, p, o: mvcjax.image_mask(p, background=o), "corner",
                        "CornerColour"),
    "background-cut": (lambda r, d, t, p, o: mvcjax.cut_out(p, background=o), "corner",
                       "CornerColour"),
}


@pytest.mark.parametrize("case", sorted(OLD_STRINGS))
def test_an_option_once_a_string_is_an_object_and_the_string_says_which(square, case):
    call, old, name = OLD_STRINGS[case]
    with pytest.raises(TypeError, match=rf"options are objects\)?; write \w+=mvcjax\.advanced\."
                                        rf"{name}\(\)"):
        call(*square, old)
    assert call(*square, getattr(mvcjax.advanced, name)()) is not None  # what it names works


def test_the_option_objects_do_what_the_strings_did(square):
    rig, renderer, targets, picture = square
    moved = targets + np.array([[0.0, 0.0], [30.0, 12.0]], np.float32)
    default = rig.deform(moved)
    np.testing.assert_array_equal(rig.deform(moved, init=mvcjax.advanced.TurnedStart()),
                                  default)
    np.testing.assert_allclose(rig.start(moved, init=mvcjax.advanced.RestStart()),
                               rig.control_mesh.vertices, atol=1e-5 * 40)
    rigid = rig.start(moved, init=mvcjax.advanced.RigidStart())
    assert not np.allclose(rigid, rig.control_mesh.vertices)
    grown = renderer(default, window=mvcjax.advanced.GrownWindow())
    assert grown.shape == (24, 24, 4)
    # The grown window holds the whole pose: its drawn area is the pose's own, which the
    # renderer's window (the rest shape's, with a margin) cuts.
    assert float(grown[..., 3].sum()) > 0
    mask = mvcjax.image_mask(picture, background=mvcjax.advanced.CornerColour())
    assert mask.sum() == 144 and mask[6:18, 6:18].all()
    tight = mvcjax.advanced.Checkerboard(cells=2).picture(4, 4)
    np.testing.assert_array_equal(tight[:2, :2, :3], np.broadcast_to(tight[0, 0, :3], (2, 2, 3)))
    assert not np.array_equal(tight[0, 0], tight[0, 2])
    with pytest.raises(ValueError, match=r"GrownWindow\(margin=\)"):
        mvcjax.advanced.GrownWindow(margin=-1.0)
    with pytest.raises(ValueError, match=r"Checkerboard\(colours=\)"):
        mvcjax.advanced.Checkerboard(colours=((1, 0, 0),))
