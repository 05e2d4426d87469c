import pathlib

ROOT = pathlib.Path(__file__).parent.parent


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text().splitlines()
    fence = readme.index("```bash")
    install_and_demo, install_and_test = readme[fence + 1], readme[fence + 2]
    assert "mvcjax demo" in install_and_demo and "pytest" in install_and_test
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert install_and_test in ci


def readme_python_blocks() -> list[str]:
    """The code of every ```python block of the README, in order."""
    blocks, block = [], None
    for line in (ROOT / "README.md").read_text().splitlines():
        if block is None and line.strip() == "```python":
            block = []
        elif block is not None and line.strip() == "```":
            blocks.append("\n".join(block))
            block = None
        elif block is not None:
            block.append(line)
    return blocks


def test_readme_example_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the example writes an animation
    blocks = readme_python_blocks()
    assert blocks, "the README has no python example"
    for index, code in enumerate(blocks):
        exec(compile(code, f"README.md python block {index}", "exec"), {"__name__": "__readme__"})
