"""User strings in the 3-D view's markdown are text: rendered by a CommonMark renderer with
raw HTML on (as viser renders it), they open no tag and read back exactly."""

from __future__ import annotations

import html
import re

import pytest
from markdown_it import MarkdownIt

from app.viewer.gui import markdown_text

HOSTILE = [
    '<iframe srcdoc="<script>parent.alert(1)</script>">',
    "<img src=x onerror=alert(1)>",
    "**bold** _it_ [link](javascript:alert(1)) `code` # heading",
    "<form action=//evil><input name=key placeholder='re-enter API key'></form>",
    "a &lt; b & c > d \\ back | pipe ~ tilde - dash. 1) 2!",
]


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_name_renders_as_its_own_text(name):
    rendered = MarkdownIt("commonmark", {"html": True}).render(markdown_text(name))
    assert re.fullmatch(r"<p>(.*)</p>\n", rendered, re.S)
    inner = rendered[3:-5]
    assert "<" not in inner and ">" not in inner  # no tag of any kind
    assert html.unescape(inner) == name
