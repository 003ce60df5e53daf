"""The console's JavaScript (``web/js``) passes ESLint, and the lint really catches bugs.

ESLint runs with the configuration ``make lint`` uses (``web/eslint.config.js``: ESLint's
recommended rules over ES modules with the browser's globals), from ``web/node_modules``
(``npm ci`` in ``web/``, which ``make lint`` runs on first use).  One Node process lints the
pages' modules and a probe module with two planted bugs, which the lint must name.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

from tests.helpers.real_components import missing

WEB = Path(__file__).resolve().parents[1] / "web"

# an unused import, an unused parameter and an undefined name; the browser's own globals
# (document, fetch) and the module's syntax (import/export, top-level await) are not findings
_PROBE = """import { get } from "./api.js";
export async function title(unusedArgument) {
  await fetch("/health");
  return document.title + undefinedName;
}
await title();
"""

_SCRIPT = """
import { ESLint } from "eslint";
const eslint = new ESLint();
const pages = await eslint.lintFiles(["js"]);
const probe = await eslint.lintText(process.env.PROBE, { filePath: "js/lint_probe.js" });
const brief = (results) => results.flatMap((r) => r.messages.map((m) =>
  ({ file: r.filePath, line: m.line, rule: m.ruleId, message: m.message })));
console.log(JSON.stringify({ files: pages.length, pages: brief(pages), probe: brief(probe) }));
"""


def _lint() -> dict[str, Any]:
    node = shutil.which("node")
    if node is None:
        missing("Node.js (the console's lint)", "no `node` on PATH (apt-get install nodejs npm)")
    if not (WEB / "node_modules" / "eslint" / "package.json").is_file():
        missing("ESLint (the console's lint)", "web/node_modules has no eslint: run `make lint` (npm ci in web/)")
    done = subprocess.run([str(node), "--input-type=module", "-e", _SCRIPT], cwd=WEB, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PROBE": _PROBE})
    assert done.returncode == 0, done.stderr
    report: dict[str, Any] = json.loads(done.stdout)
    return report


def test_the_consoles_modules_pass_eslint_and_the_lint_names_planted_bugs():
    report = _lint()
    assert report["files"] == len(list((WEB / "js").glob("*.js")))  # every module was linted
    findings = "\n".join(f"{m['file']}:{m['line']}: {m['message']} ({m['rule']})" for m in report["pages"])
    assert report["pages"] == [], "ESLint findings in web/js (cd web && npx eslint js):\n" + findings
    found = sorted((m["line"], m["rule"]) for m in report["probe"])
    assert found == [(1, "no-unused-vars"), (2, "no-unused-vars"), (4, "no-undef")], report["probe"]
    assert "undefinedName" in next(m["message"] for m in report["probe"] if m["rule"] == "no-undef")
