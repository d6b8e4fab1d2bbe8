"""``vispeech study``: run a perceptual study, export and analyse its answers."""

from __future__ import annotations

from pathlib import Path

import click

from vispeech.cli import allow_host_option, main, quiet_option
from vispeech.cli._corpus_input import cache_option, corpus_language_option, corpus_option, read_aligned_corpus
from vispeech.corpus.corpus import SPLITS


@main.group("study")
def study_group() -> None:
    """Run a perceptual study of speech animation and analyse it (docs/study.md)."""


@study_group.command("prepare")
@corpus_option
@click.option(
    "--model",
    "-m",
    "model_specs",
    multiple=True,
    required=True,
    help="A model to show: a shipped name or saved folder, or `recorded` for the corpus's own "
    "track (repeat: two at least; left to right in each clip).",
)
@click.option(
    "--split", default="test", show_default=True, type=click.Choice(list(SPLITS)), help="Where the sentences come from."
)
@click.option(
    "--sentences",
    default=10,
    show_default=True,
    type=click.IntRange(1, 200),
    help="Sentences (clips) to draw at random from the split.",
)
@click.option(
    "--seed",
    default=0,
    show_default=True,
    type=click.IntRange(min=0),
    help="Seed of the draw (and of the study's trial order).",
)
@click.option(
    "--vocode",
    is_flag=True,
    help="Play the speech through the 3-band noise vocoder (stimuli vocode), "
    "so that the faces matter for understanding it.",
)
@click.option(
    "--head",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="Render the faces on this GLB head (ARKit morph targets) instead of the 2D face "
    "(slower: about 10 heads a second).",
)
@click.option("--title", default="Talking faces", show_default=True, help="The study's title.")
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="The study folder: study.toml and clips/.",
)
@corpus_language_option
@cache_option
@quiet_option
def prepare(
    corpus_dir: Path,
    model_specs: tuple[str, ...],
    split: str,
    sentences: int,
    seed: int,
    vocode: bool,
    head: Path | None,
    title: str,
    output: Path,
    language: str,
    cache: Path | None,
    quiet: bool,
) -> None:
    """Make a study from a recorded corpus: SENTENCES of its SPLIT, each rendered with every
    --model's face side by side (the recording itself as `recorded`) and the sentence's sound
    (2D faces, or --head), and a study.toml with the rating and the pairwise task. Needs
    Chromium and Playwright (as `stimuli render`)."""
    from vispeech.errors import VispeechError
    from vispeech.files import check_output_dir
    from vispeech.models.registry import load_model
    from vispeech.study.prepare import RECORDED, STUDY_FILE, prepare_study

    if len(set(model_specs)) != len(model_specs):
        raise VispeechError("each --model once")
    check_output_dir(output, replaces=(STUDY_FILE, "clips"))
    models = {spec: None if spec == RECORDED else load_model(spec) for spec in model_specs}
    corpus = read_aligned_corpus(corpus_dir, language, cache, not quiet).split(split)
    path = prepare_study(
        corpus,
        models,
        output,
        sentences=sentences,
        seed=seed,
        vocode=vocode,
        head=head,
        title=title,
        progress=None if quiet else click.echo,
    )
    click.echo(f"study -> {path} (run it: vispeech study serve {path})")


def _database(study: Path, db: Path | None) -> Path:
    """The study's SQLite file: ``--db``, or STUDY.sqlite3 beside the TOML."""
    return db if db is not None else study.with_suffix(".sqlite3")


_db_option = click.option(
    "--db",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="SQLite file of the answers [default: STUDY.sqlite3 beside STUDY.toml].",
)


@study_group.command("serve")
@click.argument("study", type=click.Path(path_type=Path, dir_okay=False))
@_db_option
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on (0.0.0.0: every interface).")
@click.option("--port", default=8010, show_default=True, type=click.IntRange(1, 65535), help="Port to listen on.")
@click.option(
    "--admin-token",
    envvar="VISPEECH_STUDY_TOKEN",
    show_envvar=True,
    help="Token of the CSV export (/admin/answers.csv) [default: a random one, printed at start].",
)
@allow_host_option
@click.option(
    "--allow-origin",
    multiple=True,
    metavar="ORIGIN",
    help="Browser origin allowed to post answers, beside the server's own and the allowed hosts "
    "(repeatable; * for any). Others get 403.",
)
@click.option(
    "--log-level",
    default="warning",
    show_default=True,
    type=click.Choice(["critical", "error", "warning", "info", "debug"]),
    help="Server log level.",
)
def serve(
    study: Path,
    db: Path | None,
    host: str,
    port: int,
    admin_token: str | None,
    allow_host: tuple[str, ...],
    allow_origin: tuple[str, ...],
    log_level: str,
) -> None:
    """Run the study in STUDY.toml at http://HOST:PORT/ (participants: send them there, with
    ?pid=ID from a recruitment platform for one response set per id). Every answer is committed
    to the SQLite file before the page goes on. Stop with Ctrl+C."""
    import secrets

    import uvicorn

    from vispeech.guards import hosts_for
    from vispeech.study.app import create_app
    from vispeech.study.config import read_study
    from vispeech.study.store import StudyStore

    plan = read_study(study)
    store = StudyStore(_database(study, db), plan)
    token = admin_token or secrets.token_urlsafe(18)
    click.echo(f"study {plan.title!r}: {len(plan.clips)} clips, answers in {store.path}")
    click.echo(
        f"participants: http://{host}:{port}/   export: http://{host}:{port}/admin/answers.csv "
        f"(Authorization: Bearer {'<the admin token>' if admin_token else token})"
    )
    hosts = hosts_for(host, allow_host)
    app = create_app(plan, store, token, hosts, tuple(dict.fromkeys((*hosts, *allow_origin))))
    uvicorn.run(app, host=host, port=port, log_level=log_level)


@study_group.command("export")
@click.argument("study", type=click.Path(path_type=Path, dir_okay=False))
@_db_option
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder for answers.csv and participants.csv (what `study analyse` reads).",
)
def export(study: Path, db: Path | None, output: Path) -> None:
    """Write the answers of STUDY.toml's study (one row per answer, per face on a rating
    trial) and one row per participant (intro answers, checks passed) as CSV."""
    from vispeech.errors import VispeechError
    from vispeech.files import atomic_output_dir
    from vispeech.study.config import read_study
    from vispeech.study.store import StudyStore

    path = _database(study, db)
    if not path.is_file():
        raise VispeechError(f"no answers yet: {path} not found")
    answers, participants = StudyStore(path, read_study(study), create=False).export()
    with atomic_output_dir(output, replaces=("answers.csv", "participants.csv")) as folder:
        (folder / "answers.csv").write_text(answers, encoding="utf-8")
        (folder / "participants.csv").write_text(participants, encoding="utf-8")
    click.echo(f"{answers.count(chr(10)) - 1} answer rows, {participants.count(chr(10)) - 1} participants -> {output}")


@study_group.command("analyse")
@click.argument("answers", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--output",
    "-o",
    "output",
    required=True,
    type=click.Path(path_type=Path, file_okay=False),
    help="Folder for analysis.json, the CSV tables, the figures and report.html.",
)
@click.option(
    "--participants",
    type=click.Path(path_type=Path, dir_okay=False),
    default=None,
    help="participants.csv of the same export: the checks' pass counts.",
)
@click.option(
    "--exclude-failed-checks",
    is_flag=True,
    help="Leave out the participants who failed a check (needs --participants).",
)
@click.option(
    "--models",
    default=None,
    metavar="A,B,...",
    help="The models in this order, the first the reference level [default: sorted].",
)
@click.option(
    "--random-slopes/--no-random-slopes",
    default=True,
    show_default=True,
    help="Random model slopes per participant and sentence, as the thesis (about a minute a task), "
    "or random intercepts alone.",
)
def analyse(
    answers: Path,
    output: Path,
    participants: Path | None,
    exclude_failed_checks: bool,
    models: str | None,
    random_slopes: bool,
) -> None:
    """Analyse ANSWERS (answers.csv from `vispeech study export`) as the thesis did: a
    cumulative-link mixed model per task (R's ordinal::clmm), the Wald chi-square of the model
    factor, Tukey-adjusted pairs, inferred probabilities, per-sentence models, the
    proportional-odds check and win/tie/loss counts (docs/study.md). Needs R with ordinal, car,
    emmeans and jsonlite."""
    import shlex
    import sys

    from vispeech.files import check_output_dir
    from vispeech.study.analysis import analyse_answers, read_answers, read_participants
    from vispeech.study.report_folder import ANALYSIS_FILES, write_analysis

    if exclude_failed_checks and participants is None:
        raise click.UsageError("--exclude-failed-checks needs --participants")
    check_output_dir(output, replaces=ANALYSIS_FILES)
    table = read_answers(answers)
    people = read_participants(participants) if participants is not None else None
    order = [m.strip() for m in models.split(",") if m.strip()] if models else None
    analysis = analyse_answers(
        table,
        participants=people,
        exclude_failed_checks=exclude_failed_checks,
        models=order,
        random_slopes=random_slopes,
    )
    command = shlex.join(["vispeech", *sys.argv[1:]]) if sys.argv[1:3] == ["study", "analyse"] else ""
    write_analysis(analysis, output, command=command)
    for line in analysis.summary():
        click.echo(line)
    click.echo(f"analysis -> {output}/report.html")
