"""The ``vispeech`` command line: a thin layer over the library.

Each sub-command lives in a module of this package named for it; bad input ends in a
one-line ``error: ...`` message and exit code 2.
"""

from __future__ import annotations

import sys

import click

from vispeech.errors import VispeechError


class _Group(click.Group):
    """Turns library errors into one line on stderr and exit code 2."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except VispeechError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)
        except OSError as exc:
            where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
            click.echo(f"error: {exc.strerror or exc}{where}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vispeech")
def main() -> None:
    """Visual speech synthesis: text, phones or audio to talking-head animation."""


def _register_commands() -> None:
    """Import every module of this package; each adds its commands to :data:`main`."""
    import importlib
    import pkgutil

    for module in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{module.name}")


_register_commands()
