"""The web app the install builds into vispeech/serve/static: pages, bundles, no network."""

import re
from importlib.resources import files
from pathlib import Path

import pytest

PAGES = {"index.html": "chat.js", "player.html": "player.js", "viewer.html": "viewer.js"}
# Names, not addresses, never loaded: XML namespaces three.js creates elements in; the licence a VRM
# 1.0 model's meta names (three-vrm compares it), three-vrm's licence notice and a citation in its
# MToon shader's comments.
NAMESPACES = (
    "http://www.w3.org/",
    "https://vrm.dev/licenses/1.0/",
    "https://github.com/pixiv/three-vrm/blob/release/LICENSE",
    "http://hacksoflife.blogspot.ch/",
)
# Swagger UI's bundle, copied as it is, names addresses (RFC links, schema ids) it never loads;
# tests/test_serve.py checks /docs loads nothing from outside and test_browser.py renders it offline.
VENDORED = ("swagger-ui",)


@pytest.fixture(scope="module")
def static() -> Path:
    path = Path(str(files("vispeech") / "serve" / "static"))
    assert path.is_dir(), f"{path} is missing: the install should have built the web app (see setup.py)"
    return path


def page_assets(html: str) -> list[str]:
    return re.findall(r'<(?:script|link)\b[^>]*\b(?:src|href)="([^"]+)"', html)


def module_imports(js: str) -> list[str]:
    return re.findall(r'(?:\bfrom|\bimport)\s*"(\.{1,2}/[^"]+)"', js)


@pytest.mark.parametrize("page,bundle", PAGES.items())
def test_page_loads_its_bundle_and_style(static, page, bundle):
    html = (static / page).read_text(encoding="utf-8")
    assert f'<script type="module" src="static/{bundle}"></script>' in html
    for asset in page_assets(html):
        if asset.startswith("data:"):
            continue
        assert asset.startswith("static/"), f"{page} loads {asset} from outside static/"
        assert (static / asset.removeprefix("static/")).is_file(), f"{page} loads missing {asset}"
    assert "static/style.css" in page_assets(html)


def test_bundle_imports_resolve(static):
    scripts = sorted(static.rglob("*.js"))
    seen = set()
    for script in scripts:
        for spec in module_imports(script.read_text(encoding="utf-8")):
            target = (script.parent / spec).resolve()
            assert target.is_file(), f"{script.name} imports missing {spec}"
            seen.add(target)
    chunks = {p.resolve() for p in (static / "chunks").glob("*.js")}
    assert chunks and chunks <= seen, "every shared chunk is imported by a page bundle"


def test_bundle_carries_three_and_the_app(static):
    code = "\n".join(p.read_text(encoding="utf-8") for p in static.rglob("*.js"))
    assert "EXT_meshopt_compression" in code  # GLTFLoader with the meshopt decoder
    assert "VRMC_vrm" in code and "VRMC_materials_mtoon" in code  # three-vrm's loader: VRM 1.0 and 0.x, MToon
    assert "three.js authors" in code.lower()  # three's MIT licence kept in the bundle
    for name in ("influences", "frameIndex", "audioTime", "playAnimation", "seek", "speak"):
        assert re.search(rf"\b{name}\b", code), f"window.vispeech.{name} missing from the bundle"
    assert "VispeechFace2D" in (static / "face2d.js").read_text(encoding="utf-8")
    assert "vispeechStimuli" in (static / "stimuli.js").read_text(encoding="utf-8")  # stimuli render --head


def test_no_external_urls(static):
    for path in static.rglob("*"):
        if not path.is_file() or path.relative_to(static).parts[0] in VENDORED:
            continue
        text = path.read_text(encoding="utf-8")
        urls = re.findall(r"(?:https?|wss?)://[^\s\"'`)]+", text)
        urls += re.findall(r"""(?:src|href)=["']//[^"']+|url\(["']?//[^)]+""", text)
        external = [u for u in urls if not u.startswith(NAMESPACES)]
        assert not external, f"{path.name} refers to {external[:3]}"


def test_swagger_ui_is_built_in(static):
    from vispeech.serve.pages import SWAGGER_UI

    assert "SwaggerUIBundle" in (static / SWAGGER_UI["js"]).read_text(encoding="utf-8")
    assert ".swagger-ui" in (static / SWAGGER_UI["css"]).read_text(encoding="utf-8")
    assert (static / "swagger-ui" / "LICENSE").is_file()
