"""How far the models carry beyond the one speaker they learned from: other people's tracked faces and espeak-ng's voices.

    python benchmarks/bench_generalisation.py [--models NAME_OR_FOLDER ...] [--corpus NAME=DIR ...]
                                              [--json OUT.json] [--no-voices] [--sync]

Every model (by default every shipped one, ``vispeech models``) and the loudness floor
(:class:`vispeech.evaluation.floor.LoudnessFloor`: the sound's level as jawOpen) are scored by
:func:`vispeech.evaluation.evaluate_models`, as ``vispeech evaluate --channels jawOpen`` scores
them (post-processed, tracker scale, no lag), and each audio model once more with the
transcript's phones (``evaluate --transcript``, as ``animate --text`` runs it), on:

- ``grid_s1``: its test split (the models trained on its train split);
- ``grid_s4`` (``../shared/data/dev_eval/grid_s4``): another GRID speaker, all 25 utterances;
- ``natural`` (``../shared/data/dev_eval/natural``): 14 clips of TV and web speech at 25 and 30 fps, all.

``--corpus NAME=DIR`` points a corpus above at another folder, or adds one of the same layout
(scored whole: the dev_eval data and hidden sets like it are for measuring only). Printed, as
Markdown: jawOpen r per corpus, the mean over utterances of each one's r over its speech span
(the figure issue 22 tabulates; clips of 7 to 30 s make pooled frames weigh the long ones), with
r over the pooled frames beside it; the lip closures per corpus; then espeak-ng's English and
Swedish voices (``bench_audio_voices.py``): each audio model on the synthetic audio against the
default phone model (``grid-tdnn``) on espeak's own phone timings. ``--json`` saves every number.
``--sync`` moves every model's predictions by each long utterance's lag first, as ``vispeech
evaluate --sync`` does: the TV and web clips' picture leads their sound by up to 200 ms
(docs/evaluation.md), and this shows what that costs; issue 22's figures are those without.

With two models or more, a last table says whether the differences are more than the corpus can
tell apart: each row against the first one, per corpus, the mean paired difference of the
per-utterance r, Fisher's LSD p after a repeated-measures ANOVA over the table's rows
(:func:`vispeech.evaluation.statistics.compare_models`, as ``vispeech evaluate --report`` does;
the floor left out), and on how many utterances the row is higher. dev_eval's 25 and 14 clips
separate only large differences: read it before acting on one.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from bench_audio_voices import RATES, voice_scores

from vispeech.cli._corpus_input import read_aligned_corpus
from vispeech.errors import VispeechError
from vispeech.evaluation import Evaluation, evaluate_models
from vispeech.evaluation.floor import LoudnessFloor
from vispeech.evaluation.report import SYNC_MIN_SECONDS
from vispeech.evaluation.report_folder import evaluation_json
from vispeech.evaluation.report_parts import json_ready
from vispeech.evaluation.statistics import compare_models
from vispeech.files import atomic_output_file
from vispeech.models.contract import Estimator
from vispeech.models.registry import PRETRAINED, load_model
from vispeech.pipeline import DEFAULT_MODEL

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CORPORA = {
    "grid_s1": (DATA / "grid_s1", "test"),
    "grid_s4": (DATA / "dev_eval" / "grid_s4", "all"),
    "natural": (DATA / "dev_eval" / "natural", "all"),
}
"""The corpora scored by default: name → (folder, split)."""
FLOOR = "loudness floor"
TRANSCRIPT = " + transcript"
"""Appended to an audio model's label for its rows with the transcript's phones (``evaluate --transcript``)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=list(PRETRAINED), metavar="MODEL",
                        help="model names or trained model folders [default: every shipped model]")
    parser.add_argument("--corpus", action="append", default=[], metavar="NAME=DIR",
                        help="another folder for a corpus above, or one more corpus (scored whole); repeat")
    parser.add_argument("--json", type=Path, default=None, metavar="OUT", help="also save every number here")
    parser.add_argument("--no-voices", action="store_true", help="leave out espeak-ng's voices")
    parser.add_argument("--sync", action="store_true",
                        help="re-sync each utterance of 6 s or more by the phone model's lag (evaluate --sync): "
                             "how much the recordings' own audio-video offsets cost; not the figures that count")
    args = parser.parse_args()
    try:
        run(args)
    except VispeechError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)


def run(args: argparse.Namespace) -> None:
    corpora = dict(CORPORA)
    for spec in args.corpus:
        name, _, folder = spec.partition("=")
        if not name or not folder:
            raise VispeechError(f"--corpus takes NAME=DIR, got {spec!r}")
        corpora[name] = (Path(folder), corpora.get(name, (None, "all"))[1])
    if len(set(args.models)) != len(args.models):
        raise VispeechError("a model is named twice in --models")
    for folder, _ in corpora.values():
        if not folder.is_dir():
            raise VispeechError(f"corpus folder not found: {folder}")
    models: dict[str, Estimator] = {name: load_model(name) for name in args.models}
    models[FLOOR] = LoudnessFloor()

    results, seconds = {}, {}
    for name, (folder, split) in corpora.items():
        start = time.perf_counter()
        corpus = read_aligned_corpus(folder, "en", None, False).split(split)
        sync = load_model(DEFAULT_MODEL) if args.sync else None
        results[name] = evaluate_models(corpus, models, channels=["jawOpen"], sync=sync)
        with_phones = {f"{label}{TRANSCRIPT}": m for label, m in models.items() if m.input_kind == "audio"
                       and label != FLOOR}
        results[name].models += evaluate_models(corpus, with_phones, channels=["jawOpen"], transcript=True,
                                                sync=sync).models
        seconds[name] = time.perf_counter() - start
        print(f"{results[name].to_text().splitlines()[0]}: {seconds[name]:.0f} s", file=sys.stderr, flush=True)
    voices = []
    if not args.no_voices:
        start = time.perf_counter()
        audio = {label: model for label, model in models.items() if model.input_kind == "audio"}
        voices = list(voice_scores(audio, load_model(DEFAULT_MODEL)))
        seconds["espeak-ng voices"] = time.perf_counter() - start
        print(f"espeak-ng voices: {seconds['espeak-ng voices']:.0f} s", file=sys.stderr, flush=True)

    columns = {name: name if split == "all" else f"{name} {split}" for name, (_, split) in corpora.items()}
    print(markdown(models, results, columns, voices, seconds))
    if args.json is not None:
        report = {
            "command": shlex.join(["python", *sys.argv]),
            "corpora": {name: {"folder": str(folder), "split": split, **evaluation_json(results[name])}
                        for name, (folder, split) in corpora.items()},
            "voices": voices, "phone_model": DEFAULT_MODEL, "seconds": seconds,
        }
        with atomic_output_file(args.json) as tmp:
            tmp.write_text(json.dumps(json_ready(report), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def _lags(results: dict[str, Evaluation]) -> str:
    """Each re-synced corpus's lags, summed up ("" when none was re-synced)."""
    parts = []
    for name, evaluation in results.items():
        if evaluation.lags is not None:
            ms = [round(1000 * lag) for lag in evaluation.lags.values() if lag]
            parts.append(f"{name} {len(ms)} of {len(evaluation.lags)} moved" + (f", {min(ms):+d} to {max(ms):+d} ms"
                                                                               if ms else ""))
    return ", ".join(parts)


def rows(models: dict[str, Estimator]) -> list[tuple[str, str]]:
    """The table's rows, label and input: each model, then each audio model with the transcript."""
    plain = [(label, model.input_kind) for label, model in models.items()]
    return plain + [(f"{label}{TRANSCRIPT}", "audio + phones") for label, kind in plain
                    if kind == "audio" and label != FLOOR]


def markdown(models: dict[str, Estimator], results: dict[str, Evaluation], columns: dict[str, str],
             voices: list[dict], seconds: dict[str, float]) -> str:
    """The tables: jawOpen r, lip closures and (with ``voices``) espeak-ng's voices."""
    names = list(results)
    lines = ["## jawOpen r", "",
             "Mean over utterances of r over each one's speech span (r over the pooled frames in brackets); "
             "post-processed, tracker scale, " + (
                 f"each utterance of {SYNC_MIN_SECONDS:g} s or more re-synced by {DEFAULT_MODEL}'s lag (evaluate "
                 f"--sync: {synced}). " if (synced := _lags(results)) else "lag 0. ") + "; ".join(
                 f"{columns[n]}: {r.utterances} utterances, {r.models[0].scores.frames} frames" for n, r in results.items())
             + ".", "",
             "| model | input | " + " | ".join(columns[n] for n in names) + " |",
             "|---|---|" + "---:|" * len(names)]
    for label, kind in rows(models):
        cells = [f"{results[n][label].scores['jawOpen']['utterance_r']:.3f} "
                 f"({results[n][label].scores['jawOpen']['r']:.3f})" for n in names]
        lines.append(f"| {label} | {kind} | " + " | ".join(cells) + " |")

    lines += ["", "## Lip closures", "",
              "/p b m/: of the bilabials on which the speaker's lips close, how many the model closes on too; "
              "closed %: the share of speech frames with closed lips (the speaker's in the last row). The "
              "threshold assumes GRID's 360 × 288 frame: on clips filmed otherwise (natural) they are indicative "
              "only (docs/evaluation.md).", "",
              "| model | " + " | ".join(f"{columns[n]} /p b m/ | {columns[n]} closed %" for n in names) + " |",
              "|---|" + "---:|---:|" * len(names)]
    for label, _ in rows(models):
        cells = []
        for n in names:
            c = results[n][label].closures
            rate = f" ({c.bilabial_rate:.0f} %)" if c is not None and c.tracked_closures else ""
            cells += ["n/a", "n/a"] if c is None else [
                f"{c.model_closures}/{c.tracked_closures}{rate}", f"{c.model_closed_share:.1f}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    cells = []
    for n in names:
        c = results[n][FLOOR].closures
        cells += ["", "n/a" if c is None else f"{c.tracked_closed_share:.1f}"]
    lines.append("| the speaker | " + " | ".join(cells) + " |")

    if voices:
        keys = list(dict.fromkeys((row["language"], row["rate"]) for row in voices))
        lines += ["", "## espeak-ng's voices", "",
                  f"jawOpen r of each audio model on espeak-ng's audio against {DEFAULT_MODEL} on its phone timings "
                  f"(pooled over frames / mean per sentence; 10 sentences a language at rates {', '.join(map(str, RATES))}).",
                  "", "| model | " + " | ".join(f"{language} {rate:.1f}" for language, rate in keys) + " |",
                  "|---|" + "---:|" * len(keys)]
        for label in dict.fromkeys(row["model"] for row in voices):
            by_key = {(row["language"], row["rate"]): row for row in voices if row["model"] == label}
            lines.append(f"| {label} | " + " | ".join(
                f"{by_key[k]['pooled_r']:.3f} / {by_key[k]['mean_r']:.3f}" for k in keys) + " |")
    lines += ["", "Seconds: " + ", ".join(f"{name} {s:.0f}" for name, s in seconds.items()) + "."]
    compared = [label for label, _ in rows(models) if label != FLOOR]
    if len(compared) > 1:
        lines += ["", "## Paired against the first row", "",
                  f"Per-utterance jawOpen r of each row minus {compared[0]}'s: mean difference, Fisher's LSD p "
                  "(repeated-measures ANOVA over these rows), utterances where the row is higher.", "",
                  "| model | " + " | ".join(columns[n] for n in names) + " |", "|---|" + "---:|" * len(names)]
        cells = {label: [] for label in compared[1:]}
        for n in names:
            scores = {label: results[n][label].scores.per_utterance_r[:, 0] for label in compared}
            pairs = {pair.b: pair for pair in compare_models(scores, "jawOpen r").pairs if pair.a == compared[0]}
            for label in compared[1:]:
                higher = int((scores[label] > scores[compared[0]]).sum())
                p = pairs[label].p_lsd
                cells[label].append(f"{-pairs[label].difference:+.3f} (p {'< 0.01' if p < 0.01 else f'{p:.2f}'}; "
                                    f"{higher}/{len(scores[label])})")
        lines += [f"| {label} | " + " | ".join(row) + " |" for label, row in cells.items()]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
