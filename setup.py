"""Install hook: the web app in web/ is built into src/vispeech/serve/static/ on every install.

`pip install .` and `pip install -e .` run `npm ci` (only when web/node_modules is missing or
older than web/package-lock.json) and `npm run build`, then ship the built files as package
data. Without npm, already built files are used; with neither, the install stops with an
error. Set VISPEECH_SKIP_WEB_BUILD=1 to use the built files as they are. Everything else
about the package lives in pyproject.toml.
"""

import os
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

ROOT = Path(__file__).resolve().parent
WEB = ROOT / "web"
STATIC = ROOT / "src" / "vispeech" / "serve" / "static"
BUILT = ("index.html", "player.html", "viewer.html", "chat.js", "player.js", "viewer.js", "stimuli.js", "style.css", "face2d.js")


def _built() -> bool:
    return all((STATIC / name).is_file() for name in BUILT)


def _npm(npm: str, *args: str) -> None:
    print(f"vispeech web build: npm {' '.join(args)} (in {WEB})", flush=True)
    try:
        subprocess.run([npm, *args], cwd=WEB, check=True)
    except (OSError, subprocess.CalledProcessError) as err:
        raise SystemExit(
            f"error: vispeech web build failed: npm {' '.join(args)}: {err}. Fix the build, or set "
            "VISPEECH_SKIP_WEB_BUILD=1 to install the already built files in src/vispeech/serve/static/."
        ) from None


def build_web() -> None:
    """Build web/ into src/vispeech/serve/static/, or check that it was built before."""
    npm = shutil.which("npm")
    skip = os.environ.get("VISPEECH_SKIP_WEB_BUILD", "") not in ("", "0")
    if skip or npm is None or not (WEB / "package.json").is_file():
        if not _built():
            why = "VISPEECH_SKIP_WEB_BUILD is set" if skip else "npm was not found" if npm is None else "web/ is missing"
            raise SystemExit(
                f"error: vispeech needs its web app built into {STATIC}, but {why} and no built files are there. "
                "Install Node.js 18+ with npm (https://nodejs.org) and install again."
            )
        print(f"vispeech web build: skipped, using the built files in {STATIC}", flush=True)
        return
    stamp = WEB / "node_modules" / ".package-lock.json"
    lock = WEB / "package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < lock.stat().st_mtime:
        _npm(npm, "ci", "--no-audit", "--no-fund")
    _npm(npm, "run", "build")
    if not _built():
        raise SystemExit(f"error: vispeech web build: npm run build did not write {', '.join(BUILT)} into {STATIC}")


class BuildPyWithWeb(build_py):
    """build_py that builds the web app first and ships src/vispeech/serve/static/."""

    def run(self) -> None:
        build_web()
        super().run()
        if not self.editable_mode:  # an editable install reads the files from src/ directly
            target = Path(self.build_lib) / STATIC.relative_to(ROOT / "src")
            shutil.copytree(STATIC, target, dirs_exist_ok=True, ignore=shutil.ignore_patterns(".gitignore"))


class SdistWithWeb(sdist):
    """sdist that carries freshly built web files, so it installs without npm."""

    def run(self) -> None:
        build_web()
        super().run()


setup(cmdclass={"build_py": BuildPyWithWeb, "sdist": SdistWithWeb})
