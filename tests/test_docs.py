"""Every example in ``README.md`` and ``docs/*.md`` runs (as scikit-fem runs its examples).

Convention, by the info string of a fenced block (the text after the opening three backticks):

``python``
    Run by the venv's Python in a subprocess, working directory and ``PYTHONPATH`` the
    repository root.
``sh``
    Run by ``bash -e`` (the first failing command fails the example), working directory
    the repository root, the venv's ``bin`` first on ``PATH`` (so ``pushplan`` is this
    checkout's).
``python slow``, ``sh slow``
    The same, run only under ``pytest -m slow``: examples that take minutes on the
    shipped meshes (the paper's mesh, the 90-case sweep, the planner's verification mesh).
    The README's first block, ``make demo`` and ``make test``, is one of them: it writes
    ``out/`` in the repository (ignored by git) and runs the whole default suite.
    Everything else must be fast: the default examples together take well under a minute
    on two cores, so a page shows a coarse-mesh variant of a long command first.
``text``, ``toml``, ``json``, ``csv``, ``xml``
    Shown, not run.  ``toml`` blocks must parse (``tomllib``).
anything else, or no info string
    An error (``test_every_block_says_whether_it_runs``): an example must not be skipped
    silently; write ``sh`` rather than ``bash``.

Every block runs alone, in a fresh process: it sets up what it needs.  Examples write
their outputs under a temporary folder, ``out=$(mktemp -d)`` in ``sh`` and ``tempfile``
in ``python``; ``TMPDIR`` points at the test's own ``tmp_path``, so nothing is left behind.
A test case per block, its id ``file:line`` (the line of the opening fence); new pages in
``docs/`` are picked up without editing this module.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from pushplan.config import parse_scenario
from pushplan.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUN = {"python", "sh"}
SHOWN = {"text", "toml", "json", "csv", "xml"}
SLOW = "slow"
TIMEOUT_S = 120  # one fast example; each takes seconds
SLOW_TIMEOUT_S = 3600
README_MAX_LINES = 250
FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,})(?P<info>[^`]*)$")


def blocks(page: Path):
    """Fenced blocks of a Markdown page: (line of the opening fence, info string, code)."""
    found, lines, i = [], page.read_text().splitlines(), 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if m is None:
            i += 1
            continue
        start, indent, fence, body = i + 1, len(m["indent"]), m["fence"], []
        i += 1
        while i < len(lines) and not re.match(rf"^ *{fence}\s*$", lines[i]):
            body.append(lines[i][indent:] if lines[i][:indent].strip() == "" else lines[i])
            i += 1
        if i == len(lines):
            raise AssertionError(f"{page.name}:{start}: fenced block never closed")
        found.append((start, m["info"].strip(), "\n".join(body) + "\n"))
        i += 1
    return found


def _rel(page: Path) -> str:
    return str(page.relative_to(ROOT))


ALL = [(page, line, info, code) for page in PAGES for line, info, code in blocks(page)]


def _examples():
    for page, line, info, code in ALL:
        words = info.split()
        if not words or words[0] not in RUN:
            continue
        marks = [pytest.mark.slow] if SLOW in words[1:] else []
        yield pytest.param(words[0], code, id=f"{_rel(page)}:{line}", marks=marks)


def _environment(tmp_path: Path) -> dict:
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["TMPDIR"] = str(tmp_path)
    env.setdefault("MPLBACKEND", "Agg")
    return env


@pytest.mark.parametrize("language, code", list(_examples()))
def test_example_runs(language, code, tmp_path, request):
    script = tmp_path / ("example.py" if language == "python" else "example.sh")
    script.write_text(code)
    command = [sys.executable, str(script)] if language == "python" else ["bash", "-e", str(script)]
    slow = request.node.get_closest_marker("slow") is not None
    done = subprocess.run(command, cwd=ROOT, env=_environment(tmp_path), capture_output=True, text=True,
                          timeout=SLOW_TIMEOUT_S if slow else TIMEOUT_S)
    assert done.returncode == 0, (f"exit {done.returncode}\n--- stdout\n{done.stdout[-4000:]}"
                                  f"\n--- stderr\n{done.stderr[-4000:]}")


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_every_block_says_whether_it_runs(page):
    for line, info, _ in blocks(page):
        words = info.split()
        assert words, f"{_rel(page)}:{line}: a fenced block without an info string (python, sh, text, toml, ...)"
        assert (words[0] in RUN and set(words[1:]) <= {SLOW}) or (words[0] in SHOWN and len(words) == 1), \
            f"{_rel(page)}:{line}: info string {info!r} is neither run ({sorted(RUN)}, '... slow') nor shown " \
            f"({sorted(SHOWN)})"


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_toml_blocks_parse(page):
    """``toml`` blocks parse; one that is a whole scenario ([block], [material], [friction])
    is a valid scenario."""
    for line, info, code in blocks(page):
        if info == "toml":
            try:
                data = tomllib.loads(code)
            except tomllib.TOMLDecodeError as e:
                raise AssertionError(f"{_rel(page)}:{line}: {e}") from None
            if {"block", "material", "friction"} <= set(data):
                try:
                    parse_scenario(data)
                except InputError as e:
                    raise AssertionError(f"{_rel(page)}:{line}: not a valid scenario: {e}") from None


LINK = re.compile(r"\]\((?P<target>[^)\s#]+)(?:#[^)]*)?\)")


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_relative_links_resolve(page):
    """Links and pictures to files of the repository point at files that exist."""
    text = re.sub(r"(?ms)^ *```.*?^ *```", "", page.read_text())  # not inside code blocks
    missing = [m["target"] for m in LINK.finditer(text)
               if "://" not in m["target"] and not m["target"].startswith("mailto:")
               and not (page.parent / m["target"]).exists()]
    assert not missing, f"{_rel(page)}: links to missing files {missing}"


NAMED_FILE = re.compile(r"`(?P<path>(?:fe_contact|pushplan|benchmarks|tests|scenarios)/[\w/.-]+\.(?:pyx|py|toml|xml|json))")


@pytest.mark.parametrize("page", PAGES, ids=_rel)
def test_named_files_exist(page):
    """Files of the repository named in backticks (``fe_contact/fem/mesh.py``) exist."""
    missing = sorted({m["path"] for m in NAMED_FILE.finditer(page.read_text())
                      if not (ROOT / m["path"]).exists() and not (ROOT / "benchmarks" / "results" / m["path"]).exists()})
    assert not missing, f"{_rel(page)}: names files that do not exist {missing}"


def test_architecture_map_names_what_exists():
    """Each module the README's map names in a ``fe_contact/`` folder (the names that start a
    line, ``a, b  job``, and those after a semicolon, ``;  name: job``) is a module of that folder
    (tests/test_structure.py checks the converse: every module is named)."""
    block = re.search(r"## Architecture.*?```text\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    folder, named = None, []
    for line in block.splitlines():
        m = re.match(r"^  (\w+)/", line)
        if m or not line.startswith("    "):
            folder = m.group(1) if m and block.index(line) < block.index("\npushplan/") else None
            continue
        if folder is not None and line[4] != " ":  # not a continuation line
            lead = re.match(r"^ {4}([\w.]+(?:, [\w.]+)*)", line).group(1).split(", ")
            named += [(folder, n) for n in lead + re.findall(r";\s+([\w.]+):", line)]
    assert len(named) >= 30
    missing = [f"{f}/{n}" for f, n in named
               if not (ROOT / "fe_contact" / f / (n if n.endswith(".pyx") else f"{n}.py")).exists()]
    assert not missing, f"README's architecture map names what does not exist: {missing}"


def test_readme_is_a_front_door():
    """At most ~250 lines, the two commands first (``.ci/run`` calls ``make test``)."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    first = next(code for _, info, code in blocks(ROOT / "README.md"))
    assert [line.split("#")[0].strip() for line in first.splitlines()] == ["make demo", "make test"]
    assert "make test" in (ROOT / ".ci" / "run").read_text()
    makefile = (ROOT / "Makefile").read_text()
    assert re.search(r"^demo:", makefile, re.M) and re.search(r"^test:", makefile, re.M)


def test_the_extractor_sees_every_kind_of_block(tmp_path):
    """The parser itself: indented fences, longer fences, info strings with words."""
    page = tmp_path / "p.md"
    page.write_text("x\n```sh\necho a\n```\n- item\n\n  ```python slow\n  print(1)\n  ```\n"
                    "````text\n```\n````\n")
    assert blocks(page) == [(2, "sh", "echo a\n"), (7, "python slow", "print(1)\n"), (10, "text", "```\n")]


# --- issue 44: pages teach; measurements live in benchmarks/results/*.json -----------------

MEASUREMENTS_PAGE = ROOT / "docs" / "measurements.md"
MAX_MEASURED_FRACTION = 0.1
"""At most a tenth of a page's non-blank lines may be measurement tables or dated runs."""
_TIMING = re.compile(r"(?<![\w.])\d+(?:\.\d+)?\s?(?:s|ms|us|µs|min)(?![\w^])|(?<![\w.])\d+(?:\.\d+)?x\b")
_DATED = re.compile(r"\b20\d\d-\d\d-\d\d\b|\bload(?: average)?(?: of| near| at| rising to)? \d|\bmeasured on\b"
                    r"|\bat load\b|\b(?:Jan|Feb|Mar|Apr|May|Jun|Jul|Aug|Sep|Oct|Nov|Dec)[a-z]* \d{1,2},? 20\d\d\b", re.I)


def _measured_cell(cell: str) -> bool:
    """A table cell that is a measured number: two digits or more, and digits at least half
    of its letters and digits (``2.11 s``, ``0.3194 ± 0.00085``, ``20 / 20 / 20``; not
    ``"neo_hookean"``, ``z < 0`` or ``nu >= 0.4999`` in a first column), or a sentence with
    two timings or ratios (``2.11 s; step 1 0.99 s``, ``0.53x at order 363, 0.50x``)."""
    alnum = [c for c in cell if c.isalnum()]
    digits = sum(c.isdigit() for c in alnum)
    return (digits >= 2 and digits >= 0.5 * len(alnum)) or len(_TIMING.findall(cell)) >= 2


def _is_measured_row(line: str) -> bool:
    row = line.strip()
    return (row.startswith("|") and not re.fullmatch(r"\|[\s:|-]+", row)
            and any(_measured_cell(c.strip(" `*")) for c in row.strip("|").split("|")[1:]))


def measurement_lines(text: str) -> list[str]:
    """The lines of a page that are measurements rather than teaching: rows of a Markdown
    table with a measured number in a cell after the first, and dated runs: every line of a
    paragraph (or list item) with an ISO date, a load average or "measured on" in it."""
    found, paragraph = [], []

    def close():
        if any(_DATED.search(line) for line in paragraph):
            found.extend(paragraph)
        paragraph.clear()

    for line in text.splitlines():
        if _is_measured_row(line):
            close()
            found.append(line)
        elif not line.strip() or line.strip().startswith("|") or re.match(r"\s*(?:[-*]|\d+\.)\s", line):
            close()
            if line.strip() and not line.strip().startswith("|"):
                paragraph.append(line)
        else:
            paragraph.append(line)
    close()
    return found


def test_measurement_heuristic_sees_tables_and_dated_runs():
    page = ("# P\n\n| case | time (s) | ratio |\n|---|---|---|\n| a | 2.11 | 0.49x |\n| b | n/a | - |\n"
            "| c | 2.1 s; step 1 0.99 s | see [x](x.md) |\n"
            "| block | `model` |\n|---|---|\n| nu >= 0.4999 | `\"neo_hookean\"` |\n"
            "\nA run on 2 cores\n(2026-11-25 02:50, load average 5.0 rising to 6.2)\ngave this.\n"
            "\nThe load average lags by a minute.\n- one item\n- measured on a pad\n  its second line\n")
    assert measurement_lines(page) == [
        "| a | 2.11 | 0.49x |", "| c | 2.1 s; step 1 0.99 s | see [x](x.md) |",
        "A run on 2 cores", "(2026-11-25 02:50, load average 5.0 rising to 6.2)", "gave this.",
        "- measured on a pad", "  its second line"]


@pytest.mark.parametrize("page", [p for p in PAGES if p.parent.name == "docs" and p != MEASUREMENTS_PAGE],
                         ids=_rel)
def test_docs_page_teaches_rather_than_logs(page):
    """Issue 44: at most a tenth of a docs page's non-blank lines are measurement tables or
    dated runs; the numbers go to ``benchmarks/results/*.json``, rendered on the generated
    ``docs/measurements.md`` (exempt), and the history to CHANGELOG.md."""
    lines = [line for line in page.read_text().splitlines() if line.strip()]
    measured = measurement_lines(page.read_text())
    assert len(measured) <= MAX_MEASURED_FRACTION * len(lines), (
        f"{_rel(page)}: {len(measured)} of {len(lines)} lines are measurements or dated runs "
        f"(at most {MAX_MEASURED_FRACTION:.0%}):\n" + "\n".join(m[:120] for m in measured))


def test_measurements_page_is_generated_from_the_results():
    """``docs/measurements.md`` is exactly what ``benchmarks/tables.py`` renders from
    ``benchmarks/results/*.json`` (rerun the script after a benchmark)."""
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "tables.py"), "--check"], cwd=ROOT,
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    assert all(f"## {p.name}" in MEASUREMENTS_PAGE.read_text() for p in (ROOT / "benchmarks" / "results").glob("*.json"))
