"""docs/architecture.md stays drawn from the code: it names every package, and every module
file it names exists."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "vispeech"
DOC = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")


def test_every_package_is_in_the_architecture_page():
    packages = sorted(str(p.parent.relative_to(PACKAGE)) for p in PACKAGE.rglob("__init__.py") if p.parent != PACKAGE)
    missing = [p for p in packages if f"`{p}/" not in DOC and f"`{p.replace('/', '.')}`" not in DOC
               and f"`{p.rsplit('/', 1)[-1]}/`" not in DOC]
    assert not missing, f"docs/architecture.md does not name the packages {missing}"


def test_every_module_file_the_page_names_exists():
    named = set(re.findall(r"`([A-Za-z_/0-9]+\.py)`", DOC))
    modules = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")} | {
        str(p.relative_to(ROOT)) for p in (ROOT / "tests").glob("*.py")}
    missing = [name for name in sorted(named)
               if not any(m == name or m.endswith("/" + name) for m in modules)]
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"
