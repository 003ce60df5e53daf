"""The domain's small exception family.

Every layer raises one of these (or a subclass of its own); the API edge
(``app.platform.problems``) maps each class to an HTTP status and turns it into RFC 9457 problem details.  Each error
may name the offending input ``field`` (a dotted path such as ``"geometry.knots"``) and ``value`` so that the client
sees exactly what was wrong.  This module is pure: the compute core may import it.
"""

from __future__ import annotations

from typing import Any


class ConformaError(Exception):
    """Base of all expected errors.  The core knows nothing of HTTP: the API edge maps each
    class to its status and title (``app.platform.problems.http_status``)."""

    def __init__(self, message: str, *, field: str | None = None, value: Any = None) -> None:
        super().__init__(message)
        self.message = message
        self.field = field
        self.value = value


class InvalidInput(ConformaError):
    """The input is well-formed but its content cannot be used (422)."""


class NotFound(ConformaError):
    """A referenced record does not exist (404)."""


class Conflict(ConformaError):
    """The request conflicts with the current state of a record (409)."""


class TooLarge(ConformaError):
    """The request or an upload exceeds a configured limit (413)."""


class Cancelled(ConformaError):
    """A job observed its cancel request and stopped cooperatively."""
