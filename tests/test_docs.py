"""The README and the guide run as written: every ```python block of a page executed in
order, in one namespace per page, as a reader pasting them into one session would, in
a fresh folder; what the blocks print is checked where a comment says what it is."""

import contextlib
import io
import pathlib
import re
import warnings

import jax.numpy as jnp
import matplotlib
import pytest

import mvcjax
from mvcjax.solvers import DEFAULT_SOLVER

ROOT = pathlib.Path(__file__).parent.parent


def python_blocks(page: str) -> list[str]:
    """The code of every ```python block of `page`, in order."""
    blocks, block = [], None
    for line in (ROOT / page).read_text().splitlines():
        if block is None and line.strip() == "```python":
            block = []
        elif block is not None and line.strip() == "```":
            blocks.append("\n".join(block))
            block = None
        elif block is not None:
            block.append(line)
    return blocks


def printed_claims(code: str) -> list[str]:
    """What a block says it prints: the comment after each `print(...)` call whose
    comment starts with a literal result (a shape, a number, True or False)."""
    claims = []
    for line in code.splitlines():
        match = re.match(r"\s*print\(.*\)\s*#\s*(\(.*?\)|True|False|-?\d[\w.]*)", line)
        if match:
            claims.append(match.group(1))
    return claims


def run_page(page: str, folder, monkeypatch) -> tuple[list[tuple[str, str]], dict]:
    """Run `page`'s blocks in order in `folder`: each block's code and output, and the
    page's namespace."""
    monkeypatch.chdir(folder)
    matplotlib.use("Agg")  # plt.show() returns at once, as in a script without a display
    namespace = {"__name__": "__docs__"}
    seen = []
    for index, code in enumerate(python_blocks(page)):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"{page} python block {index}", "exec"), namespace)
        seen.append((code, out.getvalue()))
    return seen, namespace


@pytest.mark.parametrize("page", ["README.md", "docs/guide.md"])
def test_the_page_runs_as_written(page, tmp_path, monkeypatch):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        blocks, namespace = run_page(page, tmp_path, monkeypatch)
    assert blocks, f"{page} has no python block"
    # No picture of the page cut off at its window's edge.
    assert not [w for w in caught if "cut off" in str(w.message)], page
    # Both pages pose in JAX's default float32: the deformed vertices are float32.
    assert namespace["vertices"].dtype == jnp.float32
    for code, printed in blocks:
        lines = printed.splitlines()
        for claim in printed_claims(code):
            # A letter stands for any count: `(n, 2)` claims a shape of two columns.
            pattern = re.sub(r"(?<![\w\\'])[a-z]\w*(?![\w'])", r"\\d+", re.escape(claim))
            assert any(re.match(pattern + r"(\s|$)", line) for line in lines), (
                f"{page}: a block says it prints {claim}, got {printed!r}")


def test_the_guide_says_what_the_defaults_are():
    guide = (ROOT / "docs/guide.md").read_text()
    assert set(re.findall(r"runs (\d+) fixed-G steps", guide)) == {str(DEFAULT_SOLVER.iterations)}
    # Options are objects: a skinning is mvcjax.advanced.BlendedMVCSkinning(), not a string.
    assert not re.search(r'`"(blended|mvc|barycentric)"`', guide)
    for name in re.findall(r"`(\w+Skinning)\(\)`", guide):
        assert hasattr(mvcjax.advanced, name), name
