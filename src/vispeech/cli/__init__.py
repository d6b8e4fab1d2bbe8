"""The ``vispeech`` command line: a thin layer over the library.

Each sub-command lives in a module of this package named for it (``animate-phones`` lives
with ``say``); what several commands share lives here or in a module whose name starts with an
underscore (no command). A module is imported only when its command runs or ``--help`` lists it, and
imports what is heavy inside the command, so every command starts quickly. Bad input ends in
a one-line ``error: ...`` message and exit code 2, and so does a command whose optional
dependencies (an extra: ``pip install "vispeech[train]"``) are not installed.
"""

from __future__ import annotations

import importlib
import os
import select
import signal
import sys

import click

from vispeech.errors import VispeechError

DEFAULT_LANGUAGE = "en"
"""The default of every command's ``--language``: the language of a text, speech or corpus."""

_MODULES = {"animate-phones": "say"}
"""Commands that do not live in a module of their own name: command → module of this package."""

EXTRAS = {
    "torch": "train",
    "matplotlib": "train",
    "tqdm": "train",
    "statsmodels": "train",
    "pandas": "train",
    "sklearn": "train",
    "librosa": "train",
    "scipy": "rig",
    "fastapi": "serve",
    "starlette": "serve",
    "pydantic": "serve",
    "uvicorn": "serve",
    "websockets": "serve",
    "py3langid": "serve",
    "transformers": "encoder",
    "ray": "ray",
    "mediapipe": "capture",
    "av": "capture",
    "playwright": "test",
    "PIL": "test",
}
"""Optional top-level modules → the extra that installs them."""


def _command_names() -> set[str]:
    """Every command: one per module of this package, and the commands of :data:`_MODULES`."""
    modules = {
        name[:-3] for name in os.listdir(os.path.dirname(__file__)) if name.endswith(".py") and not name.startswith("_")
    }
    return modules | {command for command, module in _MODULES.items() if module in modules}


def language_option(help: str, default: str | None = DEFAULT_LANGUAGE):
    """The ``--language/-l`` option, the same in every command: a code in any case, passed on in
    lower case as espeak-ng and the model choices spell them (``SV`` is ``sv``)."""
    return click.option(
        "--language", "-l", default=default, show_default=default is not None, help=help, callback=_lower_case
    )


def _lower_case(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    return None if value is None else value.strip().lower()


def postprocessing_option(help: str = "How tracks are post-processed"):
    """The ``--postprocessing`` option: ``auto``, ``none`` or a preset (:data:`vispeech.postprocess.Postprocessing`)."""
    from vispeech.targets.presets import PRESETS

    return click.option(
        "--postprocessing",
        default="auto",
        show_default=True,
        type=click.Choice(["auto", "none", *PRESETS]),
        help=f"{help}: auto (what suits the model), none (its raw output) or a preset of closures, overlays "
        "and ceilings (docs/models.md).",
    )


allow_host_option = click.option(
    "--allow-host",
    multiple=True,
    metavar="NAME",
    help="Host name the server answers to, beside localhost, 127.0.0.1, ::1, --host and IP addresses "
    "(repeatable; * for any). Other Host headers get 400 (DNS rebinding).",
)
"""The ``--allow-host`` option of the servers (``serve``, ``study serve``): the Host names they answer to."""

quiet_option = click.option("--quiet", "-q", is_flag=True, help="No progress bars.")
"""The ``--quiet/-q`` flag of the commands that show progress bars."""


def scale_option(default: str):
    """The ``--scale`` option: the output scale tracks are written in (the same in every command)."""
    return click.option(
        "--scale",
        default=default,
        show_default=True,
        help="Output scale: arkit (iPhone Live Link / MetaHuman), tracker (the model's own, for evaluation) "
        "or a calibration file from `vispeech rig calibrate HEAD.glb` (docs/calibration.md).",
    )


def life_options(command):
    """``--life LAYERS`` and ``--seed``: the non-verbal layers a command adds to its tracks."""
    command = click.option(
        "--seed",
        default=0,
        show_default=True,
        type=click.IntRange(min=0),
        help="Seed of the non-verbal layers: the same seed, the same blinks and sway.",
    )(command)
    return click.option(
        "--life",
        default="",
        metavar="LAYERS",
        help="Non-verbal layers to add, comma-separated: blink, gaze, head, brows, breath, expression, or all "
        "(vispeech.motion.life) [default: none].",
    )(command)


class _Group(click.Group):
    """Imports a command's module when the command is asked for; turns errors into one line and exit code 2."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | _command_names())

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands:
            module = _MODULES.get(cmd_name, cmd_name)
            if module in _command_names():
                importlib.import_module(f"{__name__}.{module}")
        return self.commands.get(cmd_name)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except VispeechError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)
        except ModuleNotFoundError as exc:
            top = (exc.name or "").partition(".")[0]
            if top not in EXTRAS:
                raise
            command = ctx.invoked_subcommand or "this command"
            click.echo(
                f'error: vispeech {command} needs {top}, which is not installed: pip install "vispeech[{EXTRAS[top]}]"',
                err=True,
            )
            sys.exit(2)
        except BrokenPipeError as exc:
            if not _stdout_gone():  # another pipe broke (a worker's): an error like any other
                click.echo(f"error: {exc.strerror or exc}", err=True)
                sys.exit(2)
            # the reader went away (`vispeech languages | head`): end quietly, as Unix tools do
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nothing left to flush at exit
            sys.exit(128 + signal.SIGPIPE)
        except OSError as exc:
            where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
            click.echo(f"error: {exc.strerror or exc}{where}", err=True)
            sys.exit(2)


def _stdout_gone() -> bool:
    """Whether standard output is a pipe or socket whose reader has closed it (Linux reports a pipe
    so with POLLERR, macOS and sockets with POLLHUP; where it cannot be told: taken as so)."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poll.poll(0))  # HUP: macOS, sockets
    except (AttributeError, OSError, ValueError):  # no poll (Windows), or no file descriptor
        return True


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="vispeech")
def main() -> None:
    """Visual speech synthesis: text, phones or audio to talking-head animation."""
