"""The module table of docs/how-it-works.md names every module of mvcjax, and no other.

Its first column names top-level modules (`_shape.py`; a row may name several) and
subpackages as one row each (`_solvers/`), whose description names every module of the
subpackage. `__init__.py` files are the packages themselves and are not listed.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "how-it-works.md"
PACKAGE = ROOT / "mvcjax"


def table() -> list[tuple[list[str], str]]:
    """The module table's rows: the names in backticks of the first column, and the rest
    of the row."""
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    header = [i for i, line in enumerate(lines) if re.match(r"\|\s*module\s*\|", line)]
    assert len(header) == 1, f"{PAGE}: expected one table headed '| module |', found {len(header)}"
    rows = []
    for line in lines[header[0] + 2:]:  # past the header and its |---| line
        if not line.startswith("|"):
            break
        first, rest = line.strip().strip("|").split("|", 1)
        rows.append((re.findall(r"`([^`]+)`", first), rest))
    return rows


def modules(directory: Path) -> set[str]:
    """The modules of a package as the table names them: `x.py`, and `sub/` for a
    subpackage."""
    files = {p.name for p in directory.glob("*.py") if p.name != "__init__.py"}
    packages = {p.name + "/" for p in directory.iterdir()
                if p.is_dir() and (p / "__init__.py").exists()}
    return files | packages


def differences(listed: list[str], actual: set[str]) -> list[str]:
    missing = sorted(actual - set(listed))
    stale = sorted(set(listed) - actual)
    repeated = sorted({name for name in listed if listed.count(name) > 1})
    return [f"{what} {names}" for what, names in
            [("missing", missing), ("stale", stale), ("listed twice", repeated)] if names]


def test_the_module_table_names_every_module_and_no_other():
    rows = table()
    listed = [name for names, _ in rows for name in names]
    problems = differences(listed, modules(PACKAGE))
    assert not problems, (f"{PAGE.relative_to(ROOT)}'s module table against mvcjax/: "
                          + "; ".join(problems))


def test_each_subpackage_row_names_every_module_of_it():
    rows = table()
    problems = []
    for names, description in rows:
        for name in (n for n in names if n.endswith("/")):
            if not (PACKAGE / name).is_dir():
                continue  # stale, reported by the test above
            mentioned = [n for n in re.findall(r"`([^`]+)`", description)
                         if re.fullmatch(r"\w+\.py", n)]
            problems += [f"{name}: {p}" for p in differences(
                list(dict.fromkeys(mentioned)), modules(PACKAGE / name))]
    assert not problems, (f"{PAGE.relative_to(ROOT)}'s module table against the "
                          "subpackages: " + "; ".join(problems))
