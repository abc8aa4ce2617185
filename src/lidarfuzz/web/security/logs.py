"""The token never reaches a log: :class:`TokenRedaction` rewrites ``token=…`` in every record
(uvicorn's access log writes each request's path with its query, and the SSE and binary
endpoints take ``?token=``), and :func:`redact` does the same for any text that holds a URL.

Example:
    >>> redact('"GET /api/tasks/1/events?token=s3cret&x=1 HTTP/1.1" 200')
    '"GET /api/tasks/1/events?token=[redacted]&x=1 HTTP/1.1" 200'
"""

from __future__ import annotations

import logging
import re

#: ``token=VALUE`` in a query (also URL-encoded ``token%3D``), up to the next ``&``, space or quote
TOKEN_PARAMETER = re.compile(r"(?i)(\btoken(?:=|%3D))[^&\s\"']+")
REDACTED = "[redacted]"
#: The loggers a served request's URL can reach
LOGGERS = ("uvicorn.access", "uvicorn.error", "uvicorn", "lidarfuzz.web")


def redact(text: str) -> str:
    """``text`` with the value of every ``token=`` parameter replaced by ``[redacted]``."""
    return TOKEN_PARAMETER.sub(lambda match: match.group(1) + REDACTED, text)


class TokenRedaction(logging.Filter):
    """A logging filter that redacts ``token=`` in a record's message and arguments (it keeps every record)."""

    def filter(self, record: logging.LogRecord) -> bool:
        # the arguments one by one first: uvicorn's access formatter unpacks them, so they keep their shape
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: redact(v) if isinstance(v, str) else v for k, v in record.args.items()}
        try:
            message = record.getMessage()
        except (TypeError, ValueError):  # arguments that do not fit the message: the handler reports it
            return True
        redacted = redact(message)
        if redacted != message:  # 'token=%s' with the token as an argument, or in the message: the redacted text
            record.msg, record.args = redacted, ()
        return True


REDACTION = TokenRedaction()


def install_redaction() -> None:
    """Add the redaction to the loggers (and their handlers) a request's URL can reach: records
    logged there and records propagated to their handlers are redacted. Idempotent; called when
    the app starts, after uvicorn has configured its logging."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        logger.addFilter(REDACTION)
        for handler in logger.handlers:
            handler.addFilter(REDACTION)
    for handler in logging.getLogger().handlers:
        handler.addFilter(REDACTION)


__all__ = ["REDACTED", "REDACTION", "TokenRedaction", "install_redaction", "redact"]
