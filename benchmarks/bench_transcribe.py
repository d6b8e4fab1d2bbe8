"""The transcript path (``vispeech animate AUDIO --transcribe``): how well Whisper hears, how the
phone model fares on what it heard, and how long the command takes.

    python benchmarks/bench_transcribe.py [--corpus DIR] [--model MODEL] [--clip CLIP] [--runs N]
                                          [--json OUT.json]

- **natural speech** (``../shared/data/dev_eval/natural`` by default; for measuring only): the
  word error rate of :func:`vispeech.frontends.transcribe.transcribe` against the corpus's
  ``sentences.tsv`` (normalised alike: numbers and acronyms spelled out), and jawOpen r of the phone model (``grid-tdnn``) on the phones aligned
  from the recognised text against those aligned from the given transcript, both by
  :func:`vispeech.corpus.align_corpus` and scored by
  :func:`vispeech.evaluation.evaluate_models` as ``vispeech evaluate --channels jawOpen``
  scores them (post-processed, tracker scale, lag 0, over the speech span of the corpus's
  ``.align`` words): the mean over utterances of each one's r, and r over the pooled frames;
- **espeak-ng's voices**: the word error rate (normalised alike) on the acceptance sentences
  (``tests/data/sentences_{en,sv}.txt``) spoken by :func:`vispeech.pipeline.voice`, English
  by Whisper tiny.en, Swedish by Whisper base;
- **time**: ``vispeech animate CLIP --transcribe -o OUT`` as a whole process (the median of
  ``--runs``), beside ``python -c pass``, ``vispeech animate CLIP --text TRANSCRIPT`` and
  ``vispeech animate CLIP`` (the default audio model); ``--clip`` defaults to the corpus's
  10-s clip.

Printed as Markdown; ``--json`` saves every number and transcript.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from vispeech.cli._corpus_input import open_corpus, read_aligned_corpus
from vispeech.corpus import align_corpus
from vispeech.errors import VispeechError
from vispeech.evaluation import evaluate_models
from vispeech.files import atomic_output_file
from vispeech.frontends.audio import AudioClip
from vispeech.frontends.transcribe import aligner_text, transcribe, word_error_rate, words_of
from vispeech.models.registry import load_model
from vispeech.pipeline import DEFAULT_MODEL, utter

ROOT = Path(__file__).resolve().parents[1]
NATURAL = ROOT.parent / "shared" / "data" / "dev_eval" / "natural"
TEN_SECONDS = "styletalk_feifeili_clip1"
"""The 10-s clip of ``natural`` that is timed by default."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--corpus", type=Path, default=NATURAL, help="a corpus folder [default: dev_eval/natural]")
    parser.add_argument("--model", default=DEFAULT_MODEL, help=f"the phone model [default: {DEFAULT_MODEL}]")
    parser.add_argument("--clip", type=Path, default=None, help="the clip timed [default: the corpus's 10-s clip]")
    parser.add_argument("--runs", type=int, default=3, help="runs of each timed command [default: 3]")
    parser.add_argument("--json", type=Path, default=None, metavar="OUT", help="also save every number here")
    args = parser.parse_args()
    try:
        run(args)
    except VispeechError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)


def errors(reference: str, hypothesis: str, language: str) -> tuple[int, int]:
    """Words substituted, inserted and deleted, and the reference's words, the reference
    normalised as the transcript is (:func:`aligner_text`: numbers spelled out, acronyms
    spelled, ...)."""
    reference = aligner_text(reference, language)
    return round(word_error_rate(reference, hypothesis) * len(words_of(reference))), len(words_of(reference))


def natural_speech(folder: Path, model_name: str, scratch: Path) -> dict:
    """Word error rate and jawOpen r of the phone model, given transcript against recognised."""
    given = read_aligned_corpus(folder, "en", scratch / "given", False)
    heard = open_corpus(folder, "en", scratch / "heard")
    references, clips, seconds = {}, [], 0.0
    for utterance in heard:
        references[utterance.id] = utterance.text
        started = time.perf_counter()
        utterance.text = transcribe(AudioClip.from_array(*utterance.load_audio()), "en")
        seconds += time.perf_counter() - started
        utterance.phones = None
        wrong, words = errors(references[utterance.id], utterance.text, "en")
        clips.append({"id": utterance.id, "duration": utterance.duration, "errors": wrong, "words": words,
                      "heard": utterance.text})
    align_corpus(heard, scratch / "heard-alignments", progress=False)
    both = {u.id for u in given if u.phones is not None} & {u.id for u in heard if u.phones is not None}
    model = load_model(model_name)
    scores = {}
    for label, corpus in (("given transcript", given), ("recognised transcript", heard)):
        subset = replace(corpus, utterances=[u for u in corpus if u.id in both])
        jaw = evaluate_models(subset, {label: model}, channels=["jawOpen"])[label].scores["jawOpen"]
        scores[label] = {"utterance_r": jaw["utterance_r"], "r": jaw["r"]}
    return {"clips": clips, "wer": sum(c["errors"] for c in clips) / sum(c["words"] for c in clips),
            "transcribe_seconds": seconds, "audio_seconds": sum(c["duration"] for c in clips),
            "scored": sorted(both), "not_aligned": [u.id for u in heard if u.phones is None], "jawOpen": scores}


def espeak_voices() -> dict:
    """Word error rate of the transcript path on espeak-ng's voices, per language."""
    result = {}
    for language in ("en", "sv"):
        lines = (ROOT / "tests" / "data" / f"sentences_{language}.txt").read_text(encoding="utf-8").splitlines()
        rows = []
        for sentence in filter(None, map(str.strip, lines)):
            utterance = utter(sentence, language)
            heard = transcribe(AudioClip.from_array(utterance.audio, utterance.sample_rate), language)
            wrong, words = errors(sentence, heard, language)
            rows.append({"sentence": sentence, "heard": heard, "errors": wrong, "words": words})
        result[language] = {"wer": sum(r["errors"] for r in rows) / sum(r["words"] for r in rows), "sentences": rows}
    return result


def timings(clip: Path, transcript: str, runs: int, scratch: Path) -> dict[str, float]:
    """Median wall seconds of each command as a whole process."""
    vispeech = shutil.which("vispeech")
    if vispeech is None:
        raise VispeechError("the vispeech command is not on PATH (activate the virtual environment)")
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "animate --transcribe": [vispeech, "animate", str(clip), "--transcribe", "-o", str(scratch / "t")],
        "animate --text": [vispeech, "animate", str(clip), "--text", transcript, "-o", str(scratch / "x")],
        "animate (audio model)": [vispeech, "animate", str(clip), "-o", str(scratch / "a")],
    }
    result = {}
    for name, command in commands.items():
        times = []
        for _ in range(runs):
            started = time.perf_counter()
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
            times.append(time.perf_counter() - started)
        result[name] = statistics.median(times)
    return result


def run(args: argparse.Namespace) -> None:
    if not args.corpus.is_dir():
        raise VispeechError(f"corpus folder not found: {args.corpus}")
    clip = args.clip or args.corpus / "utterances" / f"{TEN_SECONDS}.flac"
    if not clip.is_file():
        raise VispeechError(f"clip not found: {clip}")
    with tempfile.TemporaryDirectory() as scratch:
        natural = natural_speech(args.corpus, args.model, Path(scratch))
        voices = espeak_voices()
        heard = {c["id"]: c["heard"] for c in natural["clips"]}
        seconds = timings(clip, heard.get(clip.stem) or transcribe(AudioClip.read(clip), "en"), args.runs,
                          Path(scratch))
    print(markdown(args, natural, voices, seconds, clip))
    if args.json is not None:
        report = {"command": shlex.join(["python", *sys.argv]), "natural": natural, "voices": voices,
                  "seconds": seconds, "clip": str(clip), "model": args.model}
        with atomic_output_file(args.json) as tmp:
            tmp.write_text(json.dumps(report, indent=2, ensure_ascii=False) + "\n", encoding="utf-8")


def markdown(args: argparse.Namespace, natural: dict, voices: dict, seconds: dict[str, float], clip: Path) -> str:
    jaw = natural["jawOpen"]
    lines = [f"## {args.corpus.name}: {len(natural['clips'])} clips, {natural['audio_seconds']:.0f} s", "",
             f"Word error rate of the transcript path against sentences.tsv: {100 * natural['wer']:.1f} % "
             f"({natural['transcribe_seconds']:.1f} s to transcribe). Not aligned: "
             f"{', '.join(natural['not_aligned']) or 'none'}.", "",
             f"jawOpen r of {args.model} (mean over utterances, pooled frames in brackets), "
             f"{len(natural['scored'])} clips:", "",
             "| phones aligned from | jawOpen r |", "|---|---:|"]
    lines += [f"| {label} | {s['utterance_r']:.3f} ({s['r']:.3f}) |" for label, s in jaw.items()]
    lines += ["", "| clip | errors / words | heard |", "|---|---:|---|"]
    lines += [f"| {c['id']} | {c['errors']}/{c['words']} | {c['heard']} |" for c in natural["clips"]]
    lines += ["", "## espeak-ng's voices", "", "| language | Whisper | word error rate |", "|---|---|---:|"]
    lines += [f"| {language} | {'tiny.en' if language == 'en' else 'base'} | {100 * v['wer']:.1f} % |"
              for language, v in voices.items()]
    lines += ["", f"## Whole-process wall time on {clip.name} (median of {args.runs})", "",
              "| command | seconds |", "|---|---:|"]
    lines += [f"| {name} | {s:.2f} |" for name, s in seconds.items()]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
