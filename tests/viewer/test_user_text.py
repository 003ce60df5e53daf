"""User strings in the 3-D view are text: in viser's markdown (rendered by a CommonMark
renderer with raw HTML on, as viser renders it) and in its HTML they open no tag and read
back exactly; as labels they read as given, on one line, without control characters."""

from __future__ import annotations

import html
import re
from html.parser import HTMLParser

import pytest
from markdown_it import MarkdownIt

from app.viewer.gui import legend_html
from app.viewer.text import user_text

HOSTILE = [
    '<iframe srcdoc="<script>parent.pwned=1</script>">',
    "<img src=x onerror=window.pwned=1>",
    "**bold** _it_ [link](javascript:alert(1)) `code` # heading",
    "<form action=//evil><input name=key placeholder='re-enter API key'></form>",
    "a &lt; b & c > d \\ back | pipe ~ tilde - dash. 1) 2! \" quote ' apostrophe",
    "![img](x) <https://evil.example> <!-- comment --> <![CDATA[x]]> &#60;script&#62;",
]


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[str] = []
        self.text = ""

    def handle_starttag(self, tag: str, attrs: list) -> None:  # type: ignore[type-arg]
        self.tags.append(tag)

    def handle_data(self, data: str) -> None:
        self.text += data


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_name_renders_as_its_own_text_in_markdown(name):  # type: ignore[no-untyped-def]
    rendered = MarkdownIt("commonmark", {"html": True}).render(user_text(name, "markdown"))
    assert re.fullmatch(r"<p>(.*)</p>\n", rendered, re.S)
    inner = rendered[3:-5]
    assert "<" not in inner and ">" not in inner  # no tag of any kind
    assert html.unescape(inner) == name


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_name_is_text_in_html_and_in_an_attribute(name):  # type: ignore[no-untyped-def]
    parsed = _Tags()
    parsed.feed(f'<div data-name="{user_text(name, "html")}">{user_text(name, "html")}</div>')
    assert parsed.tags == ["div"] and parsed.text == name


@pytest.mark.parametrize("name", HOSTILE)
def test_a_legend_named_like_markup_is_one_legend_of_text(name):  # type: ignore[no-untyped-def]
    legend = {"name": name, "title": name, "unit": name, "lo": -1.0, "hi": 1.0, "data_min": -0.5, "data_max": 0.5,
              "stops": [(0.0, "#0000ff"), (1.0, "#ff0000")]}
    parsed = _Tags()
    parsed.feed(legend_html(legend))
    assert set(parsed.tags) <= {"div", "b", "span"}
    assert parsed.text.count(name) == 3


def test_labels_read_as_given_on_one_line_without_controls_and_bounded():
    assert user_text("<b>x</b>", "label") == "<b>x</b>"
    assert user_text("a\n\tb\r\nc", "label") == "a b c"
    assert user_text("evil\u202egnp.exe\x00\u200b", "label") == "evilgnp.exe"  # bidi override, NUL, zero width
    long = user_text("x" * 1000, "label", limit=50)
    assert len(long) == 50 and long.endswith("\u2026")
    assert html.unescape(user_text("<" * 400, "html", limit=10)) == "<" * 9 + "\u2026"  # cut before escaping
    with pytest.raises(ValueError):
        user_text("x", "svg")  # type: ignore[arg-type]
