"""The docs' tables agree with the results they are written from (`tools/tables.py`):
a table edited by hand, or results rerun without the tables, fails here as in CI."""

import pathlib
import re
import sys

import pytest

ROOT = pathlib.Path(__file__).parent.parent
sys.path.insert(0, str(ROOT / "tools"))

import tables  # noqa: E402


def test_every_table_agrees_with_its_results():
    assert tables.stale() == [], "run `python tools/tables.py` to rewrite them"


def test_every_results_file_has_a_table():
    sources = {table.source for table in tables.TABLES}
    results = {str(p.relative_to(ROOT)) for p in (ROOT / tables.RESULTS).glob("*.json")}
    assert results <= sources


@pytest.mark.parametrize("name", ["deform", "folds", "table1"])
def test_a_number_edited_by_hand_is_caught(name):
    table = next(t for t in tables.TABLES if t.name == name)
    text = (ROOT / table.page).read_text()
    section = tables._section(text, table)
    match = re.search(r"\| (\d)", section)  # the first digit of a table cell
    digit = str((int(match.group(1)) + 1) % 10)
    edited = section[:match.start(1)] + digit + section[match.end(1):]
    problems = tables.stale(texts={table.page: text.replace(section, edited)})
    assert problems == [f"{table.page}: the {name} table is stale (it differs from "
                        f"{table.source})"]


def test_a_missing_section_is_named():
    table = next(t for t in tables.TABLES if t.name == "render")
    text = (ROOT / table.page).read_text().replace(table.end, "")
    problems = tables.stale(texts={table.page: text})
    assert len(problems) == 1 and "render table" in problems[0]
