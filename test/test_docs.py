"""The docs are for users: short, current, and naming only files a user can open.

No doc tells the story of how the project was made (that is git's), names a working session, or cites a file that
is not in the repository; no docstring carries a measured figure, which would go stale with the next run.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = sorted((REPO / "docs").glob("*.md"))
USER_TEXTS = [*DOCS, REPO / "README.md", *sorted((REPO / "models").glob("*.md")), REPO / "bags" / "README.md"]


GENERATED_MARK = "<!-- the table below is written by"
"""Where a doc's generated reference (``./vessel params render``) starts: it grows with the parameters, not prose."""


def _lines(path: Path) -> int:
    lines = path.read_text(encoding="utf-8").splitlines()
    prose = next((n for n, line in enumerate(lines) if line.startswith(GENERATED_MARK)), len(lines))
    return prose


def test_the_docs_are_short_enough_to_read():
    assert sum(_lines(path) for path in DOCS) < 1000, {path.name: _lines(path) for path in DOCS}
    assert _lines(REPO / "README.md") <= 200
    assert _lines(REPO / "docs" / "detector.md") <= 250


def test_no_doc_reads_as_a_lab_notebook():
    """No session, no dated note; a results page written by ``./vessel results`` says when its run was."""
    notebook = re.compile(r"\bsessions?\b|\b20\d\d-\d\d-\d\d\b", re.IGNORECASE)
    found = [f"{path.relative_to(REPO)}:{n}: {line.strip()[:80]}" for path in USER_TEXTS if path.is_file()
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if notebook.search(line)
             and not line.startswith("Written by `./vessel results")]
    assert not found, "\n".join(found)


def test_every_repository_path_a_doc_names_exists():
    tracked = set(subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                                 check=True).stdout.splitlines())
    folders = {str(Path(name).parent) for name in tracked for _ in [0]}
    folders |= {str(parent) for name in tracked for parent in Path(name).parents}
    pattern = re.compile(r"`((?:src|config|models|docs|test|bags|third_party|rosdep|\.ci)/[\w./-]*\w)/?`")
    missing = [f"{path.relative_to(REPO)}: {match}" for path in USER_TEXTS if path.is_file()
               for match in pattern.findall(path.read_text(encoding="utf-8"))
               if match not in tracked and match not in folders and "<" not in match and "*" not in match
               and not match.startswith("bags/video_") and not re.search(r"/[A-Z]+\.\w+$", match)]
    assert not missing, "\n".join(missing)


def test_no_doc_cites_a_session_output_folder():
    found = [f"{path.relative_to(REPO)}: {match}" for path in USER_TEXTS if path.is_file()
             for match in re.findall(r"out/s\d+\S*", path.read_text(encoding="utf-8"))]
    assert not found, "\n".join(found)


def test_no_docstring_carries_a_measured_figure():
    """A figure of a run (``7.2 m/100 m``, ``8.53 -> 8.13``) in a docstring; the paper's own figure may be named."""
    figure = re.compile(r"(?<![\d.])\d+(\.\d+)?\s*(m/100\s*m|m per 100 m)|\d+\.\d+\s*(->|→)\s*\d+\.\d+")
    found = []
    for path in sorted((REPO / "src").rglob("*.py")):
        if "test" in path.relative_to(REPO).parts[2:3]:
            continue
        for docstring in re.findall(r'"""(.*?)"""', path.read_text(encoding="utf-8"), re.DOTALL):
            found += [f"{path.relative_to(REPO)}: {match.group(0)}" for match in figure.finditer(docstring)
                      if not docstring[:match.start()].rstrip().endswith("paper's")]
    assert not found, "\n".join(found)
