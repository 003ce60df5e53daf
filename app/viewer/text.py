"""User strings as literal text in the 3-D view.

Every part, trace, job or machine name and every message the view shows passes through
:func:`user_text`, escaped for the viser element that shows it:

- ``"markdown"``: ``gui.add_markdown`` content.  viser renders markdown *with raw HTML*
  (its ``rehypeRawDom`` parses it with the browser's own HTML parser, unsanitised), so
  ``& < >`` become entities (no tag can open) and every markdown punctuation mark is
  backslash-escaped (no link, image, emphasis or heading of the user's making);
- ``"html"``: text or an attribute value inside ``gui.add_html`` markup (``& < > " '`` as
  entities);
- ``"label"``: a GUI label, dropdown option or plot title, which viser sets as DOM text
  (React children, uPlot's ``textContent``): left as it reads.

In all three, whitespace runs (line breaks, tabs) become one space, control and format
characters (NUL, bidirectional overrides that reorder what a name appears to say) are
dropped, and the text is cut to ``limit`` characters (with an ellipsis) before escaping.
Scene node names never carry user text: :func:`app.viewer.scenes._slug` keeps
``[A-Za-z0-9_.-]`` only.
"""

from __future__ import annotations

import html
import re
import unicodedata
from typing import Literal

Sink = Literal["markdown", "html", "label"]
DEFAULT_LIMIT = 300  # characters shown of one name or message
_MARKDOWN_PUNCTUATION = re.compile(r"([\\`*_{}\[\]()#+\-.!|~>])")


def user_text(text: object, sink: Sink, limit: int = DEFAULT_LIMIT) -> str:
    """``text`` (a user's name, or a message holding one) as literal text for ``sink``."""
    flat = " ".join(str(text).split())
    flat = "".join(c for c in flat if unicodedata.category(c) not in ("Cc", "Cf", "Cs", "Co"))
    if len(flat) > limit:
        flat = flat[:max(limit - 1, 0)] + "\u2026"
    if sink == "label":
        return flat
    if sink == "html":
        return html.escape(flat, quote=True)
    if sink == "markdown":
        return _MARKDOWN_PUNCTUATION.sub(r"\\\1", html.escape(flat, quote=False))
    raise ValueError(f"unknown sink {sink!r}: one of markdown, html, label")
