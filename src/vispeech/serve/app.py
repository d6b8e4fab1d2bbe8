"""The vispeech web server: the application that :func:`create_app` makes of the routers.

Routes (the browser contract is ``docs/web.md``; ``docs/serve.md`` describes the server):

- :mod:`~vispeech.serve.api`: ``GET /api/config``; ``POST /api/speak``; ``POST /api/animate``
  (an uploaded recording); ``GET /api/audio/<id>.wav``; ``POST /api/chat``;
- :mod:`~vispeech.serve.stream`: ``WebSocket /api/stream`` (text spoken clause by clause, or
  timed phones to frames);
- :mod:`~vispeech.serve.listen`: ``WebSocket /api/listen`` (live audio in, frames out);
- :mod:`~vispeech.serve.pages`: ``/``, ``/player``, ``/viewer`` and ``/static/...`` (the built
  web app), ``/static/face2d.js`` (the preview's 2D face), ``/avatar.glb``; the OpenAPI docs at
  ``/docs`` (Swagger UI from ``/static/``, no CDN).

Every bad request gets a 4xx JSON ``{"detail": "..."}`` (:mod:`~vispeech.serve.errors`): 422
for a malformed body, 400 for input the library refuses (or a Host not allowed), 401 without the
token (when one is configured), 403 from a foreign Origin, 413 for a body over the limit, 415 for
JSON where an audio file was wanted, 429 past the rate limit. The CPU-heavy work runs in a bounded
:class:`~vispeech.serve.pool.WorkPool`: when its queue is full the answer is 503 with
``Retry-After`` (a stream error on the WebSocket).
"""

from __future__ import annotations

import os
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool
from threadpoolctl import threadpool_limits

import vispeech
from vispeech.errors import VispeechError
from vispeech.guards import BodySizeLimit, HostOriginCheck, keep_tokens_out_of_logs
from vispeech.serve import api, listen, pages, stream
from vispeech.serve.config import CONFIG_VARIABLE, ServeConfig
from vispeech.serve.errors import EXCEPTION_HANDLERS
from vispeech.serve.pages import Site
from vispeech.serve.safety import TokenAuth
from vispeech.serve.service import SpeechService


def create_app(config: ServeConfig | None = None) -> FastAPI:
    """The FastAPI application serving ``config`` (defaults: see :class:`ServeConfig`)."""
    config = config or ServeConfig()
    keep_tokens_out_of_logs()
    site = Site.of(config)  # a missing avatar is refused before the models load
    app = FastAPI(
        title="vispeech",
        version=vispeech.__version__,
        lifespan=_lifespan,
        description="Speech animation: text to audio and ARKit blend-shape animation.",
        exception_handlers=EXCEPTION_HANDLERS,
        docs_url=None,  # pages.api_docs serves Swagger UI from /static/, not from a CDN
        redoc_url=None,
    )
    app.state.service = SpeechService(config)
    app.state.site = site
    app.add_middleware(BodySizeLimit, max_bytes=config.max_body_bytes, paths={"/api/animate": config.max_audio_bytes})
    app.add_middleware(TokenAuth, token=config.token)
    app.add_middleware(HostOriginCheck, allowed_hosts=config.allowed_hosts, allowed_origins=config.allowed_origins)
    for router in (api.router, stream.router, listen.router, pages.router):
        app.include_router(router)
    pages.mount_static(app, site.static_dir)
    return app


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Warm the service up before the first request; at the end stop its pools and close its cache."""
    service: SpeechService = app.state.service
    if service.config.switch_interval:
        # the event loop releases the GIL for every socket call and must win it back from a worker in
        # pure Python: the default 5 ms a time would slow the loop to a crawl under load
        sys.setswitchinterval(service.config.switch_interval)
    # The pool's workers run requests side by side; BLAS threads of their own on top of them
    # oversubscribe the cores and spin: with OpenBLAS's two threads a loaded 2-core server
    # spent 21.6 CPU s where one thread spent 12.0 s on the same mixed load.
    threadpool_limits(1, user_api="blas")
    await run_in_threadpool(service.warm_up)
    yield
    service.pool.close()
    service.chat_threads.shutdown(wait=False, cancel_futures=True)
    service.cache.close()


def app_from_environment() -> FastAPI:
    """The application of one of several server processes, set up from
    :data:`~vispeech.serve.config.CONFIG_VARIABLE` (uvicorn's ``factory``: each process loads its
    own models and shares the SQLite cache)."""
    text = os.environ.get(CONFIG_VARIABLE)
    if not text:
        raise VispeechError(f"{CONFIG_VARIABLE} is not set: start the processes with vispeech serve --processes N")
    return create_app(ServeConfig.from_json(text))
