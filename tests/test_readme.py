import pathlib

ROOT = pathlib.Path(__file__).parent.parent


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text().splitlines()
    fence = readme.index("```bash")
    install_and_demo, install_and_test = readme[fence + 1], readme[fence + 2]
    assert "mvcjax demo" in install_and_demo and "pytest" in install_and_test
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert install_and_test in ci
