"""The public face: what `import mvcjax` offers (`__all__`, at most 35 names), what moved
to `mvcjax.advanced`, and docs/api.md documenting every public name of both."""

import re
import types
from pathlib import Path

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
    assert public(mvcjax) - STAGES == set(mvcjax.__all__)


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
