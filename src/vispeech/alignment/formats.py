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

import bisect
import json
import math
import os
import re
from pathlib import Path
from typing import Any

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
    _check_writable(phones, path)
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


def _check_writable(phones: PhoneSequence, path: str | os.PathLike) -> None:
    """Refuse, before writing ``path``, phones that the readers would refuse: invalid ones, or a
    symbol (or language) the phone set does not have, as its label would be written."""
    phones.validate()
    for position, phone in enumerate(phones):
        label = _label(phone, phones.language)
        try:
            parse_symbol(label, phones.language)
        except VispeechError as exc:
            raise VispeechError(f"cannot write {path}: phone {position} at {phone.start:.3f} s: {exc}") from None


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

    _check_writable(phones, path)
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
    """The phones tier's and the words tier's intervals (no words tier: none) of a TextGrid."""
    tiers = _parse_textgrid(text, path)
    names = list(tiers)
    phones_name = _find_tier(names, "phones") or (names[0] if len(names) == 1 else None)
    if phones_name is None:
        raise VispeechError(f"{path} has no phones tier (tiers: {', '.join(names) or 'none'})")
    words_name = _find_tier(names, "words")
    spans: list[list[_Span]] = []
    for name in (phones_name, words_name):
        if name is None:
            spans.append([])
        elif tiers[name][0] != "IntervalTier":
            raise VispeechError(f"{path}: tier {name!r} is not an interval tier")
        else:
            spans.append([(low, high, label.strip()) for low, high, label in tiers[name][1]])
    return spans[0], spans[1]


_INTEGER = re.compile(r"[-+]?[0-9]{1,18}")
_TEXTGRID_TOKEN = re.compile(r'"(?:[^"]|"")*"|<exists>|<absent>|\[[^\]\n]*\]|[^\s"=:\[\]]+')


class _Tokens:
    """The numbers, strings and flags of a Praat text file (long or short form), with where they are.

    Praat's long form is the short one with labels (``xmin =``, ``intervals [3]:``) that carry
    no data; both read as the same stream here. A bare word is a number if :class:`float`
    reads it (``inf`` and ``nan`` too: the checks name them), else a label.
    """

    def __init__(self, text: str, path: Path):
        self.path, self.text = path, text
        self.kinds: list[str] = []
        self.values: list[Any] = []  # str for strings and flags, float for numbers
        self.offsets: list[int] = []
        for match in _TEXTGRID_TOKEN.finditer(text):
            token = match.group()
            first = token[0]
            value: Any = token
            if first == '"':
                kind, value = "string", token[1:-1].replace('""', '"')
            elif first == "<":
                kind = "flag"
            elif first == "[" or (first.isalpha() and token.lower() not in _FLOAT_WORDS):
                continue  # a label: xmin, size, intervals, [3], ...
            else:
                try:
                    kind, value = "number", float(token)
                except ValueError:
                    continue
            self.kinds.append(kind)
            self.values.append(value)
            self.offsets.append(match.start())
        self.position = 0

    def line(self, item: int | None = None) -> int:
        """The line of item number ``item``, by default the next one (the last one past the end)."""
        offsets = self.offsets
        if not offsets:
            return 1
        item = self.position if item is None else item
        return self.text.count("\n", 0, offsets[min(item, len(offsets) - 1)]) + 1

    def peek(self, item: int | None = None) -> str | None:
        """The kind of item number ``item``, by default the next one (``None`` past the end)."""
        item = self.position if item is None else item
        return self.kinds[item] if item < len(self.kinds) else None

    def take(self, kind: str, what: str, *args: object):
        """The next item, which must be of ``kind``; else an error naming ``what`` (formatted
        with ``args`` if there are any: messages are made only for errors)."""
        if self.peek() != kind:
            found = "the end of the file" if self.peek() is None else f"a {self.peek()}"
            raise VispeechError(f"{self.path}, line {self.line()}: expected {_described(what, args)}, found {found}")
        self.position += 1
        return self.values[self.position - 1]

    def time(self, what: str, *args: object) -> float:
        value = self.take("number", what, *args)
        if not (0 <= value <= MAX_DURATION_S):
            where = f"{self.path}, line {self._last_line()}: {_described(what, args)}"
            if not math.isfinite(value):
                raise VispeechError(f"{where} is not a finite number ({value})")
            if value < 0:
                raise VispeechError(f"{where} {value:g} is negative")
            raise VispeechError(f"{where} {value:g} s is past the limit of {MAX_DURATION_S:g} s")
        return value + 0.0  # -0 reads as 0

    def count(self, what: str) -> int:
        value = self.take("number", what)
        if not (math.isfinite(value) and value >= 0 and value == int(value)):
            raise VispeechError(f"{self.path}, line {self._last_line()}: {what} must be a whole number, got {value:g}")
        return int(value)

    def _last_line(self) -> int:
        """The line of the item just taken."""
        return self.line(self.position - 1)


def _described(what: str, args: tuple) -> str:
    return what.format(*args) if args else what  # a tier's name may hold braces: never a template


_FLOAT_WORDS = frozenset({"inf", "infinity", "nan"})
"""The words :class:`float` reads as numbers."""
_Tier = tuple[str, list[tuple]]
"""A TextGrid tier: its class and its entries, ``(xmin, xmax, text)`` or ``(time, mark)``."""


def _parse_textgrid(text: str, path: Path) -> dict[str, _Tier]:
    """Every tier of a TextGrid by name, its structure checked (Praat's readers are lenient).

    Times finite and non-negative, every tier inside the grid's xmin..xmax, intervals inside
    their tier, each after the previous one and not empty, points in order, tier names
    unique, and as many tiers, intervals and points as declared. Raises
    :class:`VispeechError` naming the line.
    """
    tokens = _Tokens(text, path)
    tokens.take("string", 'the file type ("ooTextFile")')
    if tokens.take("string", 'the object class ("TextGrid")') != "TextGrid":
        raise VispeechError(f'{path}: not a TextGrid (object class is not "TextGrid")')
    grid_start = tokens.time("the grid's xmin")
    grid_end = tokens.time("the grid's xmax")
    if grid_end < grid_start:
        raise VispeechError(
            f"{path}, line {tokens._last_line()}: the grid's xmax {grid_end:g} is before its xmin {grid_start:g}"
        )
    if tokens.take("flag", "<exists> or <absent>") == "<absent>":
        n_tiers = 0
    else:
        n_tiers = tokens.count("the number of tiers")
    tiers: dict[str, _Tier] = {}
    for tier in range(1, n_tiers + 1):
        if tokens.peek() is None:
            raise VispeechError(f"{path}: declares {n_tiers} tiers but holds {tier - 1}")
        line = tokens.line()
        name, parsed = _parse_tier(tokens, tier, grid_start, grid_end)
        if name in tiers:
            raise VispeechError(f"{path}, line {line}: tier {tier} has the name of an earlier one ({name!r})")
        tiers[name] = parsed
    if tokens.peek() is not None:
        raise VispeechError(f"{path}, line {tokens.line()}: data after the {n_tiers} declared tiers")
    return tiers


def _parse_tier(tokens: _Tokens, tier: int, grid_start: float, grid_end: float) -> tuple[str, _Tier]:
    """Tier number ``tier``, checked: its class, its bounds inside the grid's, and its entries."""
    path = tokens.path
    kind = tokens.take("string", f"the class of tier {tier}")
    name = tokens.take("string", f"the name of tier {tier}")
    label = f"tier {tier} ({name!r})"
    start = tokens.time(f"the xmin of {label}")
    end = tokens.time(f"the xmax of {label}")
    line = tokens._last_line()
    if end < start:
        raise VispeechError(f"{path}, line {line}: {label} ends at {end:g}, before its start {start:g}")
    if start < grid_start - TIME_TOLERANCE or end > grid_end + TIME_TOLERANCE:
        raise VispeechError(
            f"{path}, line {line}: {label} ({start:g}..{end:g} s) is outside the grid ({grid_start:g}..{grid_end:g} s)"
        )
    if kind not in ("IntervalTier", "TextTier"):
        raise VispeechError(f"{path}, line {line}: {label} has unknown class {kind!r}")
    entries = "intervals" if kind == "IntervalTier" else "points"
    parse_entry = _parse_interval if kind == "IntervalTier" else _parse_point
    declared = tokens.count(f"the number of {entries} of {label}")
    parsed = _intervals(tokens, declared, start, end) if kind == "IntervalTier" else None
    if parsed is not None:
        return name, (kind, parsed)
    parsed = []
    previous, slack = start, TIME_TOLERANCE  # intervals: only the first may start a little early
    for index in range(1, declared + 1):
        if tokens.peek() != "number":
            raise VispeechError(
                f"{path}, line {tokens.line()}: {label} declares {declared} {entries} but holds {index - 1}"
            )
        parsed.append(parse_entry(tokens, index, label, (previous, slack), end))
        previous, slack = (parsed[-1][1], 0.0) if kind == "IntervalTier" else (parsed[-1][0], slack)
    if tokens.peek() == "number":
        raise VispeechError(
            f"{path}, line {tokens.line()}: {label} holds more {entries} than the {declared} it declares"
        )
    return name, (kind, parsed)


def _intervals(tokens: _Tokens, declared: int, start: float, end: float) -> list[tuple] | None:
    """The ``declared`` intervals of a tier from ``start`` to ``end``, when they and what follows
    them pass every check of :func:`_parse_interval`, checked all at once; else ``None`` (and
    nothing taken), for the one by one reading to name what is wrong."""
    first, stop = tokens.position, tokens.position + 3 * declared
    if tokens.kinds[first:stop] != ["number", "number", "string"] * declared or tokens.peek(stop) == "number":
        return None
    values = tokens.values[first:stop]
    lows, highs = values[0::3], values[1::3]
    after = [start - TIME_TOLERANCE, *highs[:-1]]  # only the first may start a little early
    if not all(previous <= low < high for previous, low, high in zip(after, lows, highs)):
        return None
    if declared and not (lows[0] >= 0 and highs[-1] <= min(end + TIME_TOLERANCE, MAX_DURATION_S)):
        return None
    tokens.position = stop
    if declared:
        lows[0] += 0.0  # -0 reads as 0
    return list(zip(lows, highs, values[2::3]))


def _parse_interval(tokens: _Tokens, index: int, label: str, after: tuple[float, float], tier_end: float) -> tuple:
    """Interval ``index`` of a tier, ``(xmin, xmax, text)``, starting no earlier than ``after``
    (the previous end and how much earlier is the same time)."""
    first = tokens.position
    low = tokens.time("xmin of interval {} of {}", index, label)
    high = tokens.time("xmax of interval {} of {}", index, label)
    text = tokens.take("string", "the text of interval {} of {}", index, label)
    if high <= low or low < after[0] - after[1] or high > tier_end + TIME_TOLERANCE:
        where = f"{tokens.path}, line {tokens.line(first)}: interval {index} of {label}"
        if high <= low:
            raise VispeechError(f"{where} ends at {high:g}, not after its start {low:g}")
        if low < after[0] - after[1]:
            raise VispeechError(
                f"{where} starts at {low:g}, before the previous one ends ({after[0]:g}): out of order or overlapping"
            )
        raise VispeechError(f"{where} ends at {high:g}, after the tier's xmax {tier_end:g}")
    return low, high, text


def _parse_point(tokens: _Tokens, index: int, label: str, after: tuple[float, float], tier_end: float) -> tuple:
    """Point ``index`` of a tier, ``(time, mark)``, no earlier than ``after`` (as for intervals)."""
    first = tokens.position
    time = tokens.time("time of point {} of {}", index, label)
    mark = tokens.take("string", "the mark of point {} of {}", index, label)
    if time < after[0] - after[1] or time > tier_end + TIME_TOLERANCE:
        raise VispeechError(
            f"{tokens.path}, line {tokens.line(first)}: point {index} of {label} at {time:g} s "
            "is out of order or outside the tier"
        )
    return time, mark


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
        language = language or guess_language(labels, [start for start, _, _ in phone_spans])
    except VispeechError as exc:
        raise VispeechError(f"{path}: {exc}") from None
    parsed = []
    for position, (start, _, label) in enumerate(phone_spans):
        try:
            parsed.append(parse_symbol(label, language))
        except VispeechError as exc:
            raise VispeechError(f"{path}: phone {position} at {start:.3f} s: {exc}") from None
    words = [Word(label, start, end) for start, end, label in word_spans if label.lower() not in _SILENT_WORDS]
    starts = [w.start for w in words]  # in order, not overlapping: a tier's intervals
    phones = []
    for (start, end, _), (symbol, stress) in zip(phone_spans, parsed):
        word = None if is_silence(symbol) else _word_at((start + end) / 2, words, starts)
        phones.append(Phone(symbol, start, end, word, stress))
    return _validated(PhoneSequence(phones, language, words), path)


def _word_at(time: float, words: list[Word], starts: list[float]) -> int | None:
    """The word (index) whose span holds ``time``, if any."""
    i = bisect.bisect_right(starts, time) - 1
    return i if i >= 0 and time < words[i].end else None


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
    return phones_from_dict(data, str(path), language)


def phones_from_dict(data: dict, where: str, language: str | None = None) -> PhoneSequence:
    """The phones of ``data`` (:meth:`PhoneSequence.to_dict`'s form, as a JSON alignment or an
    animation JSON's ``phones`` holds it), checked as every alignment reader checks them: known
    symbols of the language (``language`` overrides the data's), times in order, the utterance
    limits. Raises :class:`VispeechError` naming ``where``."""
    try:
        phones = PhoneSequence.from_dict(data)
    except VispeechError as exc:
        raise VispeechError(f"{where}: {exc}") from None
    if language is not None:
        phones.language = language
    for position, p in enumerate(phones.phones):
        try:
            symbol, stress = parse_symbol(p.symbol, phones.language)
        except VispeechError as exc:
            raise VispeechError(f"{where}: phone {position} at {p.start:.3f} s: {exc}") from None
        if phones.language == IPA:  # IPA as written (t͡ʃ, pʰ, ˈa) reads as its segment
            phones.phones[position] = Phone(symbol, p.start, p.end, p.word, p.stress or stress)
        elif symbol != p.symbol:
            raise VispeechError(f"{where}: phone symbol {p.symbol!r} is not an inventory symbol (use {symbol!r})")
    return _validated(phones, where)


def _validated(phones: PhoneSequence, path: Path | str) -> PhoneSequence:
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
