"""The parts of a report folder, the evaluation's and a study analysis's: CSV tables, JSON-ready
numbers, figures as PNG and SVG, and an HTML page of tables and figures."""

from __future__ import annotations

import csv
import html
import math
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import numpy as np


def write_csv(path: Path, header: Sequence[str], rows: list[list]) -> None:
    """``rows`` under ``header`` as a CSV file (NaN as an empty cell)."""
    with path.open("w", newline="", encoding="utf-8") as out:
        writer = csv.writer(out)
        writer.writerow(header)
        writer.writerows([[_cell(v) for v in row] for row in rows])


def _cell(value) -> str:
    if isinstance(value, float | np.floating):
        return "" if not math.isfinite(value) else f"{float(value):.6g}"
    return str(value)


def json_ready(value):
    """JSON-ready ``value``: NaN (a score with nothing to score) becomes null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_ready(v) for v in value]
    return value


def save_figure(figure, stem: Path) -> None:
    """``figure`` as ``stem``.png and ``stem``.svg."""
    for kind in ("png", "svg"):
        figure.savefig(stem.with_suffix(f".{kind}"), format=kind)


def html_table(header: Sequence[str], rows: list[list]) -> str:
    """An HTML table of ``rows`` under ``header``."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_shown(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _shown(value) -> str:
    if isinstance(value, float | np.floating):
        if not math.isfinite(value):
            return "–"
        magnitude = cast(float | np.floating, abs(value))  # mypy joins abs() of the two types to object
        return f"{value:.3g}" if magnitude < 1e-3 and value else f"{value:.3f}"
    return str(value)


def p_text(value: float) -> str:
    """A p value as papers print it."""
    return "< 0.0001" if value < 1e-4 else f"{value:.4f}"


REPORT_STYLE = (
    "body{font-family:sans-serif;max-width:70em;margin:2em auto;padding:0 1em}"
    "table{border-collapse:collapse;margin:1em 0;font-size:90%}td,th{border:1px solid #ccc;"
    "padding:.2em .5em;text-align:right}td:first-child,th:first-child{text-align:left}"
    "img{max-width:100%}.warning{color:#a40}"
)
"""The style of the HTML reports (evaluation, study analysis)."""


def html_page(title: str, parts: Sequence[str]) -> str:
    """An HTML report page: ``title`` and the HTML ``parts`` one after another."""
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<style>{REPORT_STYLE}</style></head><body>" + "\n".join(parts) + "</body></html>\n"
    )


def html_figure(stem: str, caption: str) -> str:
    """A report's figure: ``stem``.png shown, ``stem``.svg linked."""
    return (
        f'<figure><img src="{stem}.png" alt="{html.escape(caption)}"><figcaption>{html.escape(caption)} '
        f'(<a href="{stem}.svg">SVG</a>)</figcaption></figure>'
    )
