"""Alignment files: Praat TextGrid (MFA layout), HTK ``.lab``, GRID ``.align`` and JSON.

=============  =================================================================================
``.TextGrid``  Praat TextGrid as the Montreal Forced Aligner writes it: interval tiers ``words``
               and ``phones`` (names compared case-insensitively; a lone tier is the phones).
               Empty intervals are silence.
``.lab``       HTK label file: ``start end label`` per line, times in units of 100 ns.
``.align``     GRID corpus alignment: ``start end label`` per line, times in units of 1/25000 s.
``.json``      ``{"format": "vispeech-phones", "version": 1, "language", "words", "phones"}``,
               the rest being :meth:`PhoneSequence.to_dict`.
=============  =================================================================================

Labels may carry stress as the phone sets allow (ARPAbet ``AA1``, Swedish ``'a``, IPA ``ˈa``);
the phone set is guessed from the labels unless given. IPA labels (as MFA's newer models write
them: ``tʃ``, ``aj``, ``ɑː``, ``tʰ``) read as their segments, diacritics the face does not show
dropped (:mod:`vispeech.phonetics.ipa`), in JSON too. A label that is no phone is an error
naming it, its position and its time.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

from vispeech.alignment.phones import TIME_TOLERANCE, Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.files import atomic_output_file, read_text
from vispeech.limits import MAX_DURATION_S, check_utterance, parse_json
from vispeech.phonetics.inventory import IPA, guess_language, is_silence, is_vowel, parse_symbol

JSON_FORMAT = "vispeech-phones"
"""The ``format`` tag of the JSON alignment form."""

_UNITS_PER_SECOND = {".lab": 10_000_000, ".align": 25_000}
_SILENT_WORDS = frozenset({"", "sil", "sp", "<eps>"})
_SWEDISH_STRESS_MARKS = {1: "'", 2: '"'}
_IPA_STRESS_MARKS = {1: "ˈ", 2: "ˌ"}

_Span = tuple[float, float, str]


def read_alignment(path: str | os.PathLike, language: str | None = None) -> PhoneSequence:
    """Read a phone alignment, choosing the format by the file's extension.

    Parameters
    ----------
    path : .TextGrid, .lab, .align or .json file.
    language : ``"sv"`` or ``"en"``; guessed from the phone labels when ``None``.

    Returns a validated :class:`PhoneSequence` (times in seconds). Raises
    :class:`VispeechError` for a missing, empty or malformed file, an unknown phone symbol,
    or intervals that overlap or run backwards.
    """
    path = Path(path)
    suffix = _suffix(path)
    text = read_text(path, "alignment file")
    if suffix == ".json":
        return _from_json(text, path, language)
    if suffix == ".textgrid":
        phones, words = _textgrid_spans(path, text)
    else:
        phones, words = _table_spans(text, path, _UNITS_PER_SECOND[suffix]), []
    return _build(phones, words, path, language)


def write_alignment(phones: PhoneSequence, path: str | os.PathLike) -> None:
    """Write ``phones`` in the format named by the extension of ``path`` (atomically)."""
    path = Path(path)
    suffix = _suffix(path)
    phones.validate()
    if suffix == ".textgrid":
        write_textgrid(phones, path)
        return
    if suffix == ".json":
        text = json.dumps({"format": JSON_FORMAT, "version": 1, **phones.to_dict()}, indent=1) + "\n"
    else:
        units = _UNITS_PER_SECOND[suffix]
        text = "".join(
            f"{round(p.start * units)} {round(p.end * units)} {_label(p, phones.language)}\n" for p in phones
        )
    with atomic_output_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def read_textgrid(path: str | os.PathLike, language: str | None = None) -> PhoneSequence:
    """Read an MFA-style TextGrid (see :func:`read_alignment`)."""
    path = Path(path)
    text = read_text(path, "alignment file")
    phones, words = _textgrid_spans(path, text)
    return _build(phones, words, path, language)


def write_textgrid(phones: PhoneSequence, path: str | os.PathLike) -> None:
    """Write ``phones`` as a long-format TextGrid with ``words`` and ``phones`` tiers.

    Silence phones keep their label (``sil``, ``sp``) so that they survive a round trip;
    time not covered by any phone or word becomes an empty interval. The file is written
    atomically.
    """
    from praatio import textgrid  # imported here: only TextGrids need praatio
    from praatio.utilities.constants import Interval

    phones.validate()
    end = max(phones.duration, max((w.end for w in phones.words), default=0.0))
    grid = textgrid.Textgrid(minTimestamp=0.0, maxTimestamp=end)
    word_entries = [Interval(w.start, w.end, w.text) for w in phones.words]
    phone_entries = [Interval(p.start, p.end, _label(p, phones.language)) for p in phones]
    grid.addTier(textgrid.IntervalTier("words", word_entries, 0.0, end))
    grid.addTier(textgrid.IntervalTier("phones", phone_entries, 0.0, end))
    with atomic_output_file(path) as tmp:
        grid.save(str(tmp), format="long_textgrid", includeBlankSpaces=True, reportingMode="silence")


def read_word_alignment(path: str | os.PathLike) -> list[Word]:
    """Word timings (seconds) from a word-level ``.align``/``.lab`` file, a TextGrid's
    ``words`` tier or the JSON form; silence labels (``sil``, ``sp``) are skipped.

    GRID's own ``.align`` files are word-level, e.g. ``23750 29500 bin``.
    """
    path = Path(path)
    suffix = _suffix(path)
    text = read_text(path, "alignment file")
    if suffix == ".json":
        return _from_json(text, path, None).words
    if suffix == ".textgrid":
        spans = _textgrid_spans(path, text)[1]
    else:
        spans = _table_spans(text, path, _UNITS_PER_SECOND[suffix])
    return [Word(label, start, end) for start, end, label in spans if label.lower() not in _SILENT_WORDS]


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in (".textgrid", ".json", *_UNITS_PER_SECOND):
        raise VispeechError(
            f"unknown alignment format {path.suffix!r} for {path} (use .TextGrid, .lab, .align or .json)"
        )
    return suffix


def _table_spans(text: str, path: Path, units: int) -> list[_Span]:
    """``start end label`` lines: integer times, non-negative, each span after the previous one;
    a pause (``sil``, ``sp``) that lasts nothing is dropped."""
    spans: list[_Span] = []
    previous_end = 0
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        if not fields:
            continue
        where = f"{path}, line {number}"
        if len(fields) < 3 or not all(_INTEGER.fullmatch(f) for f in fields[:2]):
            raise VispeechError(f"{where}: expected 'start end label' (integer times), got {_excerpt(line)}")
        start, end = int(fields[0]), int(fields[1])
        if start < 0 or end < 0:
            raise VispeechError(f"{where}: negative time {min(start, end)}")
        if end == start and fields[2].lower() in _SILENT_WORDS:
            continue  # an empty pause (forced aligners write one at a clip's end) marks nothing
        if end <= start:
            raise VispeechError(f"{where}: the span ends at {end}, not after its start {start}")
        if end / units > MAX_DURATION_S:
            raise VispeechError(f"{where}: time {end / units:g} s is past the limit of {MAX_DURATION_S:g} s")
        if start < previous_end:
            raise VispeechError(f"{where}: the span starts at {start}, before the previous one ends ({previous_end})")
        previous_end = end
        spans.append((start / units, end / units, fields[2]))
    return spans


def _excerpt(line: str, width: int = 60) -> str:
    line = line.strip()
    return repr(line if len(line) <= width else line[:width] + "...")


def _textgrid_spans(path: Path, text: str) -> tuple[list[_Span], list[_Span]]:
    from praatio import textgrid

    _check_textgrid(text, path)
    try:
        grid = textgrid.openTextgrid(str(path), includeEmptyIntervals=True, reportingMode="silence")
    except Exception as exc:  # praatio raises assorted exception types on malformed input
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise VispeechError(f"malformed TextGrid {path}: {detail[:200]}") from None
    names = list(grid.tierNames)
    phones_name = _find_tier(names, "phones") or (names[0] if len(names) == 1 else None)
    if phones_name is None:
        raise VispeechError(f"{path} has no phones tier (tiers: {', '.join(names) or 'none'})")
    words_name = _find_tier(names, "words")
    tiers = [grid.getTier(name) for name in (phones_name, words_name) if name is not None]
    for tier in tiers:
        if not isinstance(tier, textgrid.IntervalTier):
            raise VispeechError(f"{path}: tier {tier.name!r} is not an interval tier")
    phones = [(float(e.start), float(e.end), e.label.strip()) for e in tiers[0].entries]
    words = [(float(e.start), float(e.end), e.label.strip()) for e in tiers[1].entries] if words_name else []
    return phones, words


_INTEGER = re.compile(r"[-+]?[0-9]{1,18}")
_TEXTGRID_TOKEN = re.compile(r'"(?:[^"]|"")*"|<exists>|<absent>|\[[^\]\n]*\]|[^\s"=:\[\]]+')


class _Tokens:
    """The numbers, strings and flags of a Praat text file (long or short form), with line numbers.

    Praat's long form is the short one with labels (``xmin =``, ``intervals [3]:``) that carry
    no data; both read as the same stream here.
    """

    def __init__(self, text: str, path: Path):
        self.path = path
        self.items: list[tuple[str, object, int]] = []
        line, last = 1, 0
        for match in _TEXTGRID_TOKEN.finditer(text):
            line += text.count("\n", last, match.start())
            last = match.start()
            token = match.group()
            if token.startswith('"'):
                self.items.append(("string", token[1:-1].replace('""', '"'), line))
            elif token.startswith("<"):
                self.items.append(("flag", token, line))
            elif not token.startswith("["):
                try:
                    self.items.append(("number", float(token), line))
                except ValueError:
                    pass  # a label: xmin, size, intervals, ...
        self.position = 0
        self.end_line = line

    def line(self) -> int:
        return self.items[self.position][2] if self.position < len(self.items) else self.end_line

    def peek(self) -> str | None:
        return self.items[self.position][0] if self.position < len(self.items) else None

    def take(self, kind: str, what: str):
        if self.peek() != kind:
            found = "the end of the file" if self.peek() is None else f"a {self.peek()}"
            raise VispeechError(f"{self.path}, line {self.line()}: expected {what}, found {found}")
        value = self.items[self.position][1]
        self.position += 1
        return value

    def time(self, what: str) -> float:
        line = self.line()
        value = self.take("number", what)
        if not math.isfinite(value):
            raise VispeechError(f"{self.path}, line {line}: {what} is not a finite number ({value})")
        if value < 0:
            raise VispeechError(f"{self.path}, line {line}: {what} {value:g} is negative")
        if value > MAX_DURATION_S:
            raise VispeechError(
                f"{self.path}, line {line}: {what} {value:g} s is past the limit of {MAX_DURATION_S:g} s"
            )
        return value

    def count(self, what: str) -> int:
        line = self.line()
        value = self.take("number", what)
        if not (math.isfinite(value) and value >= 0 and value == int(value)):
            raise VispeechError(f"{self.path}, line {line}: {what} must be a whole number, got {value:g}")
        return int(value)


def _check_textgrid(text: str, path: Path) -> None:
    """Check a TextGrid's structure before praatio reads it (praatio is lenient).

    Times finite and non-negative, every tier inside the grid's xmin..xmax, intervals inside
    their tier, each after the previous one and not empty, points in order, and as many
    tiers, intervals and points as declared. Raises :class:`VispeechError` naming the line.
    """
    tokens = _Tokens(text, path)
    tokens.take("string", 'the file type ("ooTextFile")')
    if tokens.take("string", 'the object class ("TextGrid")') != "TextGrid":
        raise VispeechError(f'{path}: not a TextGrid (object class is not "TextGrid")')
    grid_start = tokens.time("the grid's xmin")
    line = tokens.line()
    grid_end = tokens.time("the grid's xmax")
    if grid_end < grid_start:
        raise VispeechError(f"{path}, line {line}: the grid's xmax {grid_end:g} is before its xmin {grid_start:g}")
    if tokens.take("flag", "<exists> or <absent>") == "<absent>":
        n_tiers = 0
    else:
        n_tiers = tokens.count("the number of tiers")
    for tier in range(1, n_tiers + 1):
        if tokens.peek() is None:
            raise VispeechError(f"{path}: declares {n_tiers} tiers but holds {tier - 1}")
        _check_tier(tokens, tier, grid_start, grid_end)
    if tokens.peek() is not None:
        raise VispeechError(f"{path}, line {tokens.line()}: data after the {n_tiers} declared tiers")


def _check_tier(tokens: _Tokens, tier: int, grid_start: float, grid_end: float) -> None:
    """Check tier number ``tier``: its class, its bounds inside the grid's, and its entries."""
    path = tokens.path
    kind = tokens.take("string", f"the class of tier {tier}")
    name = tokens.take("string", f"the name of tier {tier}")
    label = f"tier {tier} ({name!r})"
    start = tokens.time(f"the xmin of {label}")
    line = tokens.line()
    end = tokens.time(f"the xmax of {label}")
    if end < start:
        raise VispeechError(f"{path}, line {line}: {label} ends at {end:g}, before its start {start:g}")
    if start < grid_start - TIME_TOLERANCE or end > grid_end + TIME_TOLERANCE:
        raise VispeechError(
            f"{path}, line {line}: {label} ({start:g}..{end:g} s) is outside the grid ({grid_start:g}..{grid_end:g} s)"
        )
    if kind not in ("IntervalTier", "TextTier"):
        raise VispeechError(f"{path}, line {line}: {label} has unknown class {kind!r}")
    entries = "intervals" if kind == "IntervalTier" else "points"
    check_entry = _check_interval if kind == "IntervalTier" else _check_point
    declared = tokens.count(f"the number of {entries} of {label}")
    previous = start
    for index in range(1, declared + 1):
        if tokens.peek() != "number":
            raise VispeechError(
                f"{path}, line {tokens.line()}: {label} declares {declared} {entries} but holds {index - 1}"
            )
        previous = check_entry(tokens, index, label, previous, end)
    if tokens.peek() == "number":
        raise VispeechError(
            f"{path}, line {tokens.line()}: {label} holds more {entries} than the {declared} it declares"
        )


def _check_interval(tokens: _Tokens, index: int, label: str, previous: float, tier_end: float) -> float:
    """Check interval ``index`` of a tier, after the one ending at ``previous``; returns its end."""
    line = tokens.line()
    low = tokens.time(f"xmin of interval {index} of {label}")
    high = tokens.time(f"xmax of interval {index} of {label}")
    tokens.take("string", f"the text of interval {index} of {label}")
    where = f"{tokens.path}, line {line}: interval {index} of {label}"
    if high <= low:
        raise VispeechError(f"{where} ends at {high:g}, not after its start {low:g}")
    if low < previous - TIME_TOLERANCE:
        raise VispeechError(
            f"{where} starts at {low:g}, before the previous one ends ({previous:g}): out of order or overlapping"
        )
    if high > tier_end + TIME_TOLERANCE:
        raise VispeechError(f"{where} ends at {high:g}, after the tier's xmax {tier_end:g}")
    return high


def _check_point(tokens: _Tokens, index: int, label: str, previous: float, tier_end: float) -> float:
    """Check point ``index`` of a tier, after the one at ``previous``; returns its time."""
    line = tokens.line()
    time = tokens.time(f"time of point {index} of {label}")
    tokens.take("string", f"the mark of point {index} of {label}")
    if time < previous - TIME_TOLERANCE or time > tier_end + TIME_TOLERANCE:
        raise VispeechError(
            f"{tokens.path}, line {line}: point {index} of {label} at {time:g} s is out of order or outside the tier"
        )
    return time


def _find_tier(names: list[str], kind: str) -> str | None:
    """The tier called ``kind`` (any case), or MFA's multi-speaker ``<speaker> - kind``."""
    exact = [n for n in names if n.strip().lower() == kind]
    if exact:
        return exact[0]
    speaker = [n for n in names if n.strip().lower().endswith(f" - {kind}")]
    return speaker[0] if speaker else None


def _build(phone_spans: list[_Span], word_spans: list[_Span], path: Path, language: str | None) -> PhoneSequence:
    if not phone_spans:
        raise VispeechError(f"alignment file has no phones: {path}")
    labels = [label for _, _, label in phone_spans]
    try:
        language = language or guess_language(labels)
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None
    parsed = []
    for position, (start, _, label) in enumerate(phone_spans):
        try:
            parsed.append(parse_symbol(label, language))
        except VispeechError as exc:
            raise VispeechError(f"{path}: phone {position} at {start:.3f} s: {exc}") from None
    words = [Word(label, start, end) for start, end, label in word_spans if label.lower() not in _SILENT_WORDS]
    phones = []
    for (start, end, _), (symbol, stress) in zip(phone_spans, parsed):
        word = None if is_silence(symbol) else _word_at((start + end) / 2, words)
        phones.append(Phone(symbol, start, end, word, stress))
    return _validated(PhoneSequence(phones, language, words), path)


def _word_at(time: float, words: list[Word]) -> int | None:
    for i, w in enumerate(words):
        if w.start <= time < w.end:
            return i
    return None


def _from_json(text: str, path: Path, language: str | None) -> PhoneSequence:
    data = parse_json(text, str(path))
    if not isinstance(data, dict) or data.get("format", JSON_FORMAT) != JSON_FORMAT:
        raise VispeechError(f"{path} is not a {JSON_FORMAT} file")
    if not isinstance(data.get("phones"), list):
        raise VispeechError(f"{path}: 'phones' must be a list")
    if not isinstance(data.get("words", []), list):
        raise VispeechError(f"{path}: 'words' must be a list")
    check_utterance(0.0, len(data["phones"]), str(path))
    if data.get("version", 1) != 1:
        raise VispeechError(f"{path}: unsupported {JSON_FORMAT} version {data.get('version')!r}")
    try:
        phones = PhoneSequence.from_dict(data)
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None
    if language is not None:
        phones.language = language
    for position, p in enumerate(phones.phones):
        try:
            symbol, stress = parse_symbol(p.symbol, phones.language)
        except VispeechError as exc:
            raise VispeechError(f"{path}: phone {position} at {p.start:.3f} s: {exc}") from None
        if phones.language == IPA:  # IPA as written (t͡ʃ, pʰ, ˈa) reads as its segment
            phones.phones[position] = Phone(symbol, p.start, p.end, p.word, p.stress or stress)
        elif symbol != p.symbol:
            raise VispeechError(f"{path}: phone symbol {p.symbol!r} is not an inventory symbol (use {symbol!r})")
    return _validated(phones, path)


def _validated(phones: PhoneSequence, path: Path) -> PhoneSequence:
    check_utterance(max((p.end for p in phones), default=0.0), len(phones), str(path))
    try:
        phones.validate()
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None
    if any(p.start < 0 for p in phones):
        raise VispeechError(f"{path}: phone 0 starts at a negative time ({phones.phones[0].start:g} s)")
    if any(not (math.isfinite(w.start) and math.isfinite(w.end)) or w.end < w.start for w in phones.words):
        raise VispeechError(f"{path}: a word ends before it starts")
    return phones


def _label(phone: Phone, language: str) -> str:
    """The file label of ``phone``: ARPAbet vowels with their stress digit, Swedish and IPA stress marks."""
    if is_silence(phone.symbol):
        return phone.symbol
    if language == "en":
        return f"{phone.symbol}{phone.stress}" if is_vowel(phone.symbol, "en") else phone.symbol
    marks = _IPA_STRESS_MARKS if language == IPA else _SWEDISH_STRESS_MARKS
    return marks.get(phone.stress, "") + phone.symbol
