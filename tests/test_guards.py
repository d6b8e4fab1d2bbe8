"""The web servers' shared guards: secrets kept out of uvicorn's logs."""

from __future__ import annotations

import io
import logging

import pytest
from conftest import require_module

require_module("uvicorn", "uvicorn (the serve extra)")
from uvicorn.logging import AccessFormatter, DefaultFormatter  # noqa: E402

from vispeech.guards import RedactTokens, keep_tokens_out_of_logs, redact_tokens  # noqa: E402


def test_token_query_values_are_redacted():
    assert redact_tokens("/?token=s3cret") == "/?token=[redacted]"
    assert redact_tokens("/admin/answers.csv?x=1&token=abc&y=2") == "/admin/answers.csv?x=1&token=[redacted]&y=2"
    assert redact_tokens("/api/stream?admin_token=abc#top") == "/api/stream?admin_token=[redacted]#top"
    assert redact_tokens("/?tokens=1&page=token=x") == "/?tokens=1&page=token=x"


@pytest.fixture
def uvicorn_logs():
    """What uvicorn's access and error loggers write, through uvicorn's own formatters."""
    out = io.StringIO()
    handlers = []
    for name, formatter in (("uvicorn.access", AccessFormatter('%(client_addr)s - "%(request_line)s" %(status_code)s')),
                            ("uvicorn.error", DefaultFormatter("%(message)s"))):
        handler = logging.StreamHandler(out)
        handler.setFormatter(formatter)
        logging.getLogger(name).addHandler(handler)
        logging.getLogger(name).setLevel(logging.INFO)
        handlers.append((name, handler))
    yield out
    for name, handler in handlers:
        logging.getLogger(name).removeHandler(handler)


def test_uvicorn_logs_carry_no_token(uvicorn_logs):
    keep_tokens_out_of_logs()
    keep_tokens_out_of_logs()  # once is enough: no second filter
    assert sum(isinstance(f, RedactTokens) for f in logging.getLogger("uvicorn.access").filters) == 1
    # the calls uvicorn's HTTP and WebSocket protocols make
    logging.getLogger("uvicorn.access").info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5000", "GET", "/?token=s3cret",
                                             "1.1", 200)
    logging.getLogger("uvicorn.error").info('%s - "WebSocket %s" [accepted]', "127.0.0.1:5001",
                                            "/api/stream?token=s3cret")
    written = uvicorn_logs.getvalue()
    assert "s3cret" not in written
    assert '"GET /?token=[redacted] HTTP/1.1" 200' in written
    assert '"WebSocket /api/stream?token=[redacted]" [accepted]' in written
