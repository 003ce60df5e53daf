"""The manual (docs/) and the README that leads to it.

* the manual builds with mkdocs-material's strict build, offline, without a single warning;
* the README is a door: at most 150 lines, and every page it links to exists;
* ``docs/architecture.md`` names every package of ``app/`` and ``hardware/``;
* no page, module or test speaks of internal work items or of the method sources by number:
  a reader meets what a thing is, never which ticket asked for it.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from tests.helpers.real_components import missing

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CONFIG = DOCS / "config" / "mkdocs.yml"
README = ROOT / "README.md"


def _build(site: Path) -> subprocess.CompletedProcess[str]:
    """``mkdocs build --strict`` into ``site`` with every proxy pointing at a closed port, so a
    build that reached for the network would fail (and without the theme's end-of-life banner,
    which is not about the manual)."""
    dead = "http://127.0.0.1:9"
    env = {**os.environ, "HTTP_PROXY": dead, "HTTPS_PROXY": dead, "http_proxy": dead, "https_proxy": dead,
           "NO_PROXY": "", "no_proxy": "", "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(CONFIG),
                           "--site-dir", str(site)], capture_output=True, text=True, env=env, timeout=240)


def test_the_manual_builds_strictly_offline_without_a_warning(tmp_path):
    try:
        import material  # noqa: F401
        import mkdocs  # noqa: F401
    except ImportError as error:
        missing("mkdocs-material", f"{error} (pip install -e '.[docs]')")
    run = _build(tmp_path / "site")
    output = run.stdout + run.stderr
    assert run.returncode == 0, output
    assert not re.search(r"warning", output, re.I), output
    for page in ("index", "install", "architecture", "measured", "methods"):
        assert (tmp_path / "site" / f"{page}.html").is_file(), page


def test_the_manual_config_has_nothing_that_reaches_the_network():
    text = CONFIG.read_text()
    plugins = re.search(r"^plugins:\n((?:\s+- .*\n)+)", text, re.M)
    assert plugins and [p.strip(" -") for p in plugins.group(1).splitlines()] == ["search"]
    assert re.search(r"^\s+font: false$", text, re.M), "web fonts are fetched by the reader's browser"


def test_every_page_is_in_the_navigation_and_every_nav_entry_exists():
    nav = set(re.findall(r":\s+([\w-]+\.md)$", CONFIG.read_text(), re.M))
    pages = {p.name for p in DOCS.glob("*.md")}
    assert nav == pages


def test_the_readme_is_a_door():
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    links = re.findall(r"\]\((docs/[^)#]+)", text)
    assert len(links) >= 10
    assert [link for link in links if not (ROOT / link).is_file()] == []
    for command in ("make run", "make test"):
        assert command in text
        target = command.split()[1]
        assert re.search(rf"^{target}:", (ROOT / "Makefile").read_text(), re.M)


def test_the_architecture_page_names_every_package():
    page = (DOCS / "architecture.md").read_text()
    packages = sorted(f"{p.parent.relative_to(ROOT)}/" for top in ("app", "hardware")
                      for p in (ROOT / top).glob("*/__init__.py"))
    assert len(packages) >= 15
    unnamed = [p for p in packages if p.split("/", 1)[1] not in page]
    assert unnamed == [], "draw the new package in docs/architecture.md"


# written split so that this file does not match itself
_WORK_ITEMS = re.compile(r"\b(?:issue|stop)\s?#?\d+\b(?![.,]\d)|\bseed\s+(?:S\d|eq)|\bS\d\s?\.\.\s?S\d\b", re.I)
_TEXT = {".py", ".md", ".js", ".html", ".css", ".toml", ".yml", ".yaml", ".ini", ".hal", ".ngc", ".txt", ".json",
         ".tsv", ".cfg", ".sh"}


def _text_files() -> list[Path]:
    files = [README, ROOT / "pyproject.toml", ROOT / "Makefile", ROOT / ".ci" / "run"]
    for top in ("docs", "app", "hardware", "web", "tests"):
        files += [p for p in (ROOT / top).rglob("*") if p.is_file() and p.suffix in _TEXT
                  and not {"artifacts", "__pycache__", "node_modules"} & set(p.parts)]
    return files


def test_no_work_items_or_source_numbers_in_docs_or_code():
    found = [f"{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}" for path in _text_files()
             for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1) if _WORK_ITEMS.search(line)]
    assert found == [], "say what it is, not which work item asked for it:\n" + "\n".join(found)


def test_the_work_item_check_sees_them():
    for line in ("# iss" "ue 14: strict", "see iss" "ue #7", "on st" "op 23's run", "the se" "ed S1 method",
                 "se" "ed eq. 1", "S1." ".S5"):
        assert _WORK_ITEMS.search(line), line
    for line in ("the S1 reference part", "30 stops", "issued 3 commands", "seed=11", "stop(1)",
                 "start / stop 2.1-2.5 s"):
        assert not _WORK_ITEMS.search(line), line
