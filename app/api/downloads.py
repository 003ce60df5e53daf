"""Content-Disposition for downloads (RFC 6266 / RFC 8187): any file name, safely.

``attachment; filename="<ASCII fallback>"; filename*=UTF-8''<percent-encoded name>``: old
clients get a plain ASCII name, current ones the real one (``ключ.csv``); quotes,
backslashes, control characters and path separators never reach the header.
"""

from __future__ import annotations

import unicodedata
from urllib.parse import quote


def _ascii(text: str) -> str:
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    return "".join(c if c.isalnum() or c in "_- " else "_" for c in text).strip(" _")


def attachment(name: str) -> str:
    """The header value that downloads ``name`` as an attachment."""
    name = "".join(c for c in name.replace("/", "_").replace("\\", "_") if unicodedata.category(c)[0] != "C")
    name = name.strip() or "download"
    stem, _, extension = name.rpartition(".") if "." in name.strip(".") else (name, "", "")
    fallback = (_ascii(stem) or "download") + (f".{_ascii(extension)}" if _ascii(extension) else "")
    return f"attachment; filename=\"{fallback}\"; filename*=UTF-8''{quote(name, safe='')}"
