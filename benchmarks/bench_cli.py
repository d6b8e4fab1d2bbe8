"""Whole-process start-up of the command line, on one core.

    python benchmarks/bench_cli.py [--runs N] [--model NAME]

Times, as the median (and minimum) wall time of N runs of a fresh process each:

- ``python -c pass``: the interpreter alone, for scale, and ``vispeech --help``;
- ``vispeech animate-phones TAKE.TextGrid -o DIR``: a 3-s utterance (the second golden
  sentence, tests/golden/phones.json, written as a TextGrid by
  :func:`vispeech.alignment.formats.write_alignment`);
- ``vispeech say "SENTENCE" -o DIR``: the same sentence spoken by espeak-ng;
- ``vispeech animate SPEECH.wav --language en|sv -o DIR``: 10 s of espeak-ng speech (the
  golden sentences, or the Swedish acceptance sentences, spoken one after another, cut to 10 s)
  animated from the audio alone by the language's default audio model
  (:func:`vispeech.pipeline.default_audio_model`: ``grid-audio-whisper``, and
  ``grid-audio-whisper-base`` for Swedish, where the whisper extra is installed);
- espeak-ng's own synthesis of that sentence in-process
  (:func:`vispeech.frontends.espeak.synthesize`): the first call in a process and later
  calls (every call loads the library and the voice afresh, so that a text always sounds
  the same; later calls find the files in the page cache).

Targets (issue 7): animate-phones ≤ 0.6 s; say ≤ 0.6 s plus espeak-ng's first-call time;
(issue 22) animate of 10 s of audio ≤ 1.5 s.
Every process is pinned to one CPU with OpenMP/OpenBLAS/MKL threads set to 1, and may keep
Python's bytecode cache as an installed package does (``PYTHONDONTWRITEBYTECODE`` is dropped
from its environment: where it is set, as on the development machine, an editable install
otherwise compiles every module of vispeech afresh in every process, about 0.15 s); the
untimed warm-up run of each command writes the cache.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GOLDEN_PHONES = ROOT / "tests" / "golden" / "phones.json"
SWEDISH_SENTENCES = ROOT / "tests" / "data" / "sentences_sv.txt"
TARGET = 0.6
"""Seconds: the whole-process target of animate-phones, and of say beyond espeak-ng's own time."""
ANIMATE_TARGET = 1.5
"""Seconds: the whole-process target of animate on :data:`ANIMATE_SECONDS` of audio."""
ANIMATE_SECONDS = 10.0
CPU = min(os.sched_getaffinity(0))

_ESPEAK_TIMER = """
import json, sys, time
from vispeech.frontends.espeak import synthesize
text, runs = sys.argv[1], int(sys.argv[2])
times = []
for _ in range(runs + 1):
    start = time.perf_counter()
    synthesize(text, "en")
    times.append(time.perf_counter() - start)
print(json.dumps(times))
"""


CHILD_ENV = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
"""The environment of the timed processes: this one's, with the bytecode cache allowed."""


def _pin() -> None:
    os.sched_setaffinity(0, {CPU})


def vispeech_command() -> list[str]:
    """The installed ``vispeech`` script beside this interpreter, else ``python -c`` on the entry point."""
    script = Path(sys.executable).with_name("vispeech")
    if script.is_file():
        return [str(script)]
    found = shutil.which("vispeech")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; from vispeech.cli import main; sys.exit(main())"]


def wall_times(command: list[str], runs: int, cwd: Path) -> list[float]:
    """Wall seconds of ``runs`` runs of ``command`` (after one untimed warm-up run); stops on a failure."""
    times = []
    for i in range(runs + 1):
        start = time.perf_counter()
        result = subprocess.run(command, cwd=cwd, capture_output=True, text=True, preexec_fn=_pin, env=CHILD_ENV)
        elapsed = time.perf_counter() - start
        if result.returncode != 0:
            raise SystemExit(f"{' '.join(command)} failed ({result.returncode}):\n{result.stderr}")
        if i:
            times.append(elapsed)
    return times


def make_take(folder: Path) -> tuple[Path, str, float]:
    """The 3-s TextGrid of golden sentence 1, its text and its duration."""
    from vispeech.alignment.formats import write_alignment
    from vispeech.alignment.phones import PhoneSequence

    entry = json.loads(GOLDEN_PHONES.read_text(encoding="utf-8"))[1]
    phones = PhoneSequence.from_dict(entry)
    path = folder / "take.TextGrid"
    write_alignment(phones, path)
    return path, entry["text"], phones.duration


def make_speech(folder: Path, language: str = "en") -> Path:
    """:data:`ANIMATE_SECONDS` of espeak-ng speech as a WAV file: the golden sentences (``en``) or the
    Swedish acceptance sentences (``sv``) one after another."""
    import numpy as np
    import soundfile

    from vispeech.pipeline import utter

    if language == "en":
        texts = [entry["text"] for entry in json.loads(GOLDEN_PHONES.read_text(encoding="utf-8"))]
    else:
        texts = [line.strip() for line in SWEDISH_SENTENCES.read_text(encoding="utf-8").splitlines() if line.strip()]
    parts, rate = [], None
    for text in texts:
        utterance = utter(text, language)
        parts.append(utterance.audio)
        rate = utterance.sample_rate
        if sum(len(p) for p in parts) >= ANIMATE_SECONDS * rate:
            break
    path = folder / f"speech_{language}.wav"
    soundfile.write(path, np.tile(np.concatenate(parts), 2)[:round(ANIMATE_SECONDS * rate)], rate)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=7, help="Timed runs per command (median reported).")
    parser.add_argument("--model", default=None, help="--model for animate-phones and say [default: theirs].")
    args = parser.parse_args()
    _pin()
    vispeech = vispeech_command()
    model = ["--model", args.model] if args.model else []
    with tempfile.TemporaryDirectory(prefix="bench_cli_") as tmp:
        tmp = Path(tmp)
        take, text, duration = make_take(tmp)
        rows = [
            ("python -c pass", wall_times([sys.executable, "-c", "pass"], args.runs, tmp), None),
            ("vispeech --help", wall_times([*vispeech, "--help"], args.runs, tmp), None),
            (f"vispeech animate-phones ({duration:.2f}-s TextGrid)",
             wall_times([*vispeech, "animate-phones", str(take), "-o", str(tmp / "take"), *model], args.runs, tmp),
             TARGET),
        ]
        espeak = subprocess.run([sys.executable, "-c", _ESPEAK_TIMER, text, str(args.runs)], capture_output=True,
                                text=True, preexec_fn=_pin, check=True)
        first, *warm = json.loads(espeak.stdout)
        rows.append(("espeak-ng synthesize, first call in a process", [first], None))
        rows.append(("espeak-ng synthesize, later calls", warm, None))
        say = wall_times([*vispeech, "say", text, "-o", str(tmp / "say"), *model], args.runs, tmp)
        rows.append((f'vispeech say "{text}"', say, TARGET + first))
        from vispeech.pipeline import default_audio_model

        for language, name in (("en", "English"), ("sv", "Swedish")):
            speech = make_speech(tmp, language)
            command = [*vispeech, "animate", str(speech), "--language", language, "-o", str(tmp / "animate")]
            rows.append((f"vispeech animate ({ANIMATE_SECONDS:g}-s {name} WAV, {default_audio_model(language)})",
                         wall_times(command, args.runs, tmp), ANIMATE_TARGET))

    print(f"one core (CPU {CPU}), {args.runs} runs each, model {args.model or 'default'}; seconds")
    print(f"{'':<66} {'median':>7} {'min':>7} {'target':>7}")
    for name, times, target in rows:
        median = statistics.median(times)
        mark = "" if target is None else f"{target:7.3f} {'ok' if median <= target else 'OVER'}"
        print(f"{name[:66]:<66} {median:7.3f} {min(times):7.3f} {mark}")
    print(f"say minus espeak-ng's first call: {statistics.median(say) - first:.3f} s (target {TARGET} s)")


if __name__ == "__main__":
    main()
