"""``vispeech languages``: every language `--language` takes."""

from __future__ import annotations

import json

import click

from vispeech.cli import main


@main.command("languages")
@click.option("--json", "as_json", is_flag=True, help="Print a JSON list instead of a table.")
@click.option(
    "--voices", "list_voices", is_flag=True, help="List the voices (for --voice) instead: espeak-ng's variants."
)
def languages_command(as_json: bool, list_voices: bool) -> None:
    """List the languages espeak-ng speaks here: code, other codes, phones, name.

    sv and en are read into their curated phone inventories; every other language into IPA
    phones whose articulatory features come from the IPA, so every model animates them.
    Any language speaks with any voice (say --voice f3, serve --voice m1).
    """
    from vispeech.frontends.espeak import languages, voices

    if list_voices:
        found = voices()
        if as_json:
            click.echo(json.dumps([{"voice": k, "gender": v} for k, v in found.items()], indent=1))
            return
        for gender in ("female", "male", ""):
            names = [k for k, v in found.items() if v == gender]
            click.echo(f"{gender or 'other'} ({len(names)}): {' '.join(names)}")
        return
    listed = languages()
    if as_json:
        click.echo(
            json.dumps(
                [
                    {"language": v.code, "aliases": list(v.aliases), "phones": v.phones, "name": v.name.strip()}
                    for v in listed
                ],
                ensure_ascii=False,
                indent=1,
            )
        )
        return
    rows = [("code", "also", "phones", "name")]
    rows += [(v.code, ",".join(v.aliases), "curated" if v.phones != "ipa" else "ipa", v.name.strip()) for v in listed]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    for row in rows:
        click.echo("  ".join(cell.ljust(width) for cell, width in zip(row, widths)) + "  " + row[-1])
    click.echo(f"\n{len(listed)} languages (espeak-ng's voices with their dictionaries).")
