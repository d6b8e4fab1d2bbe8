"""``vispeech models``: what can run now, and what it was trained on."""

from __future__ import annotations

import click

from vispeech.cli import main


@main.command("models")
def models_command() -> None:
    """List the models --model takes: name, family, input, look-ahead, training data, test-split score.

    Families that must be trained first (the networks) are reached through `vispeech train`.
    """
    from vispeech.models.registry import DATA_FREE, FAMILIES, PRETRAINED, describe_models, family_class

    rows = [("name", "family", "input", "look-ahead", "trained on", "test split")]
    for info in describe_models():
        ahead = f"{info.lookahead} frames" + (f" at {info.fps:g} fps" if info.fps else "")
        rows.append((info.name, info.family, info.input, ahead, info.trained_on, info.score))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]) - 1)]
    for row in rows:
        click.echo("  ".join(cell.ljust(width) for cell, width in zip(row, widths)) + "  " + row[-1])
    trainable = [family for family in FAMILIES if family_class(family).trainable]
    click.echo(
        f"\n{len(PRETRAINED)} shipped, {len(DATA_FREE)} data-free. "
        f"Train your own with: vispeech train --model {{{','.join(trainable)}}}"
    )
