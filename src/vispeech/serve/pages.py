"""What a browser opens: the web app's pages and scripts (``/``, ``/player``, ``/viewer``,
``/static/...``), the preview's 2D face (``/static/face2d.js``), the avatar (``/avatar.glb``)
and the API docs (``/docs``, Swagger UI served from the built web app, so that it works offline);
none of them in the OpenAPI description."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, FastAPI, HTTPException, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.requests import HTTPConnection

import vispeech.preview
from vispeech.errors import VispeechError
from vispeech.serve.config import ServeConfig

log = logging.getLogger("vispeech.serve")

STATIC_DIR = Path(__file__).parent / "static"
"""Where ``web/build.mjs`` puts the built web app."""

PAGES = {"/": "index.html", "/player": "player.html", "/viewer": "viewer.html"}
"""Each page's path and its file in the built web app."""

_NOT_BUILT = "the web app is not built: run `npm run build` in web/"
SWAGGER_UI = {"js": "swagger-ui/swagger-ui-bundle.js", "css": "swagger-ui/swagger-ui.css"}
"""Swagger UI's script and style sheet in the built web app (``web/build.mjs`` copies them)."""
_FACE2D = Path(vispeech.preview.__file__).parent / "face2d.js"


@dataclass(frozen=True)
class Site:
    """What the pages serve: the built web app's folder and the avatar's file, with its bytes
    prepared for the page (``None``: served as it is)."""

    static_dir: Path
    avatar: Path | None
    avatar_bytes: bytes | None

    @classmethod
    def of(cls, config: ServeConfig) -> Site:
        """The site of ``config``, its avatar prepared once (the shipped head is shipped prepared);
        :class:`VispeechError` when the avatar file is missing or no GLB or VRM file, or the 2D face is asked
        for as well (a head at a URL is the browser's to load: the site has no file)."""
        if config.avatar is not None and not config.head:
            raise VispeechError("give --avatar or --face-2d, not both")
        avatar = config.head_file
        if avatar is not None and not avatar.is_file():
            raise VispeechError(f"avatar file not found: {avatar}")
        if avatar is not None:
            with open(avatar, "rb") as handle:
                if handle.read(4) != b"glTF":  # GLB and VRM files begin so; a head the browser cannot load
                    raise VispeechError(f"avatar {avatar} is not a binary glTF (.glb) or VRM file")
        prepare = config.avatar is not None and config.prepare_avatar
        prepared = _avatar_bytes(avatar) if avatar is not None and prepare else None
        return cls(Path(config.static_dir or STATIC_DIR), avatar, prepared)


def _avatar_bytes(path: Path) -> bytes | None:
    """The head at ``path`` prepared for the page (:func:`~vispeech.motion.rigging.head.prepared_head`), or None
    (served as it is) when it cannot be: the reason is logged."""
    from vispeech.motion.rigging.head import prepared_head

    try:
        data, report = prepared_head(path)
    except VispeechError as exc:
        log.warning("serving %s as it is: %s", path, exc)
        return None
    for note in report.notes:
        log.info("avatar %s: %s", path.name, note)
    return data


async def _site(connection: HTTPConnection) -> Site:
    return connection.app.state.site


SiteOf = Annotated[Site, Depends(_site)]
"""A route parameter given the application's :class:`Site`."""

router = APIRouter(include_in_schema=False)


@router.get("/avatar.glb")
def avatar(site: SiteOf) -> Response:
    """The head, prepared (or as it is); 404 when the pages show the 2D face or load the head from a URL."""
    if site.avatar is None or not site.avatar.is_file():
        raise HTTPException(404, "no avatar file: the pages show the 2D face or load the head from its URL")
    if site.avatar_bytes is not None:
        return Response(site.avatar_bytes, media_type="model/gltf-binary")
    return FileResponse(site.avatar, media_type="model/gltf-binary")


@router.get("/static/face2d.js")
def face2d_script() -> FileResponse:
    """The preview's 2D face, which the pages draw when there is no head."""
    return FileResponse(_FACE2D, media_type="text/javascript")


def _page(name: str) -> Callable[[Site], FileResponse]:
    def page(site: SiteOf) -> FileResponse:
        path = site.static_dir / name
        if not path.is_file():
            raise HTTPException(404, _NOT_BUILT)
        return FileResponse(path, media_type="text/html")

    return page


@router.get("/docs")
def api_docs(request: Request, site: SiteOf) -> HTMLResponse:
    """Swagger UI on ``/openapi.json``, every asset from ``/static/`` (no CDN, no validator badge)."""
    if not all((site.static_dir / name).is_file() for name in SWAGGER_UI.values()):
        raise HTTPException(404, _NOT_BUILT)
    root = request.scope.get("root_path", "")
    return get_swagger_ui_html(
        openapi_url=f"{root}{request.app.openapi_url}",
        title=f"{request.app.title} API",
        swagger_js_url=f"{root}/static/{SWAGGER_UI['js']}",
        swagger_css_url=f"{root}/static/{SWAGGER_UI['css']}",
        swagger_favicon_url="data:,",
        swagger_ui_parameters={"validatorUrl": None},
    )


for _path, _name in PAGES.items():
    router.add_api_route(_path, _page(_name), methods=["GET"])


def mount_static(app: FastAPI, static_dir: Path) -> None:
    """Serve ``/static/...`` from the built web app, or 404 with a hint when it is not built."""
    if static_dir.is_dir():
        app.mount("/static", StaticFiles(directory=static_dir), name="static")
    else:
        app.add_api_route("/static/{path:path}", _not_built, methods=["GET"], include_in_schema=False)


def _not_built(path: str) -> Response:
    raise HTTPException(404, _NOT_BUILT)
