"""What of a text is spoken: chat-model replies carry Markdown, links and emoji that a voice
must not read out ("slightly smiling face", "asterisk asterisk", "h t t p s colon ...").

:func:`speakable` parses the text as CommonMark (markdown-it-py) and keeps the words of its
paragraphs, headings, list items and quotes (emphasis marks dropped, a link's text kept, its
address not, inline code kept as words), leaves out code blocks, HTML and images, drops bare
``http(s)://`` and ``www.`` addresses, and removes every emoji (the ``emoji`` package's list,
skin tones and joiners included), control character and terminal escape sequence. Blocks that
end without punctuation get a full stop, so a list is read as a list. Plain text comes back as
it was, but for white space runs folded to one space. :func:`detect_language` tells which of
some languages a text is written in.

:func:`split_clauses` cuts a text into the sentences and clauses a stream speaks one at a time;
:class:`ClauseReader` does the same for a text that arrives in pieces (a chat model's streamed
reply), giving each clause as soon as it is known to be whole.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import cache
from typing import NamedTuple

from vispeech.errors import VispeechError

_URL = re.compile(r"(?:\bhttps?://|\bwww\.)\S*[^\s.,;:!?)\]'\"”’]", re.IGNORECASE)
_SPACE = re.compile(r"\s+")
_CONTROL = re.compile(  # a terminal's escape sequences, then C0 and C1 controls but tab, line and page breaks
    r"\x1b\[[0-?]*[ -/]*[@-~]|[\x00-\x08\x0b\x0e-\x1f\x7f-\x84\x86-\x9f]"
)
_GONE = "\x00"  # where a link or an emoji was taken out
_GAP_BEFORE_PUNCTUATION = re.compile(r"\s*\x00[\s\x00]*(?=[,.;:!?…])")
_ENDS_SENTENCE = re.compile(r"[.!?…:;]['\"”’)\]]*$")


@cache
def _parser():
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark")


def speakable(text: str) -> str:
    """``text`` as it should be spoken: Markdown's words without its markup, no links, no emoji."""
    import emoji

    blocks: list[str] = []
    for token in _parser().parse(_CONTROL.sub("", text)):
        if token.type != "inline":
            continue
        words = _SPACE.sub(" ", "".join(_inline_text(token.children or []))).strip()
        if words:
            blocks.append(words)
    spoken = []
    for i, block in enumerate(blocks):
        block = emoji.replace_emoji(_URL.sub(_GONE, block), _GONE)
        block = _SPACE.sub(" ", _GAP_BEFORE_PUNCTUATION.sub("", block).replace(_GONE, " ")).strip(" \u200d\ufe0f")
        if not block:
            continue
        if i < len(blocks) - 1 and not _ENDS_SENTENCE.search(block):
            block += "."
        spoken.append(block)
    return " ".join(spoken)


def _inline_text(children) -> list[str]:
    """The words of an inline token's children: text and code; line breaks and inline HTML as
    spaces; images (their alt text) left out. Code blocks and HTML blocks are not inline tokens."""
    parts: list[str] = []
    for child in children:
        if child.type in ("text", "code_inline"):
            parts.append(child.content)
        elif child.type in ("softbreak", "hardbreak", "html_inline"):
            parts.append(" ")
    return parts


LANGUAGE_CONFIDENCE = 0.9
"""Probability (among the candidates) above which :func:`detect_language` names a language."""
_LANGID_CODES = {"cmn": "zh", "yue": "zh", "nb": "no", "fr-fr": "fr", "es-419": "es", "pt-br": "pt", "hyw": "hy"}


def detect_language(text: str, candidates: Iterable[str], confidence: float = LANGUAGE_CONFIDENCE) -> str | None:
    """Which of ``candidates`` (``vispeech languages`` codes) ``text`` is written in, or ``None``
    when no candidate is at least ``confidence`` likely among them (a short "ok", "Hej!").

    py3langid (a maintained langid.py: naive Bayes over byte n-grams, 97 languages) ranks the
    text; the candidates' probabilities are renormalised among themselves. Codes langid does
    not know are never named.
    """
    by_code: dict[str, list[str]] = {}
    for code in candidates:
        by_code.setdefault(_LANGID_CODES.get(code, code.split("-")[0]), []).append(code)
    ranked = [(p, code) for code, p in _identifier().rank(text) if code in by_code]
    total = sum(p for p, _ in ranked)
    if not ranked or total <= 0:
        return None
    best_p, best = max(ranked)
    return by_code[best][0] if best_p / total >= confidence else None


@cache
def _identifier():
    try:
        from py3langid.langid import MODEL_FILE, LanguageIdentifier
    except ImportError:
        raise VispeechError("telling a text's language needs py3langid (the serve extra)") from None
    return LanguageIdentifier.from_model_file(MODEL_FILE, norm_probs=True)


_CLAUSE_BREAK = re.compile(r"(?<=[.!?;:,…])\s+")
_FENCE = re.compile(r"\s*(```|~~~)")
_SENTENCE_END = re.compile(r"[.!?…:]['\"”’)\]]*$")


class Clause(NamedTuple):
    """A clause of a text; ``ends_sentence``: it ends with ``. ! ? …``, a colon (what follows may
    be in another language: a quote) or its line."""

    text: str
    ends_sentence: bool


def split_clauses(text: str) -> list[str]:
    """Sentences and clauses of ``text`` (:class:`ClauseReader`'s, of the whole text at once)."""
    reader = ClauseReader()
    return [clause.text for clause in [*reader.feed(text), *reader.finish()]]


class ClauseReader:
    """The clauses of a text fed in pieces, each given out once it is whole.

    A clause ends after ``. ! ? ; : , …`` followed by white space, and at a line break, so
    ``"3.5"`` and ``"1,000"`` stay whole; a piece without a letter or digit joins the clause
    before it (the one after when it leads). A clause is given out once a letter or digit
    follows its break, so nothing is added to it afterwards and :meth:`finish` gives the last
    one. The lines of a fenced code block (```) are left out.
    """

    def __init__(self) -> None:
        self._line = ""  # the current line's text not given out yet
        self._fresh = True  # whether it begins its line
        self._code = False  # inside a fenced code block
        self._held: Clause | None = None  # the last whole clause, given out once a letter or digit follows
        self._lead = ""  # leading pieces with nothing to say

    def feed(self, text: str) -> list[Clause]:
        """The clauses ``text`` completes (the text fed so far, and ``text``)."""
        out: list[Clause] = []
        self._line += text
        while "\n" in self._line:
            line, self._line = self._line.split("\n", 1)
            self._read(line, True, out)
            self._fresh = True
        self._line = self._read(self._line, False, out)
        return out

    def finish(self) -> list[Clause]:
        """The clauses left once the text has ended (the reader is done)."""
        out: list[Clause] = []
        self._read(self._line, True, out)
        if self._held is not None:
            out.append(self._held)
        elif self._lead.strip():
            out.append(Clause(self._lead.strip(), True))
        return out

    def _read(self, line: str, ended: bool, out: list[Clause]) -> str:
        """Add the clauses of ``line`` to ``out`` (all of them when the line has ``ended``, else
        those a break closes); the rest of the line, to read when more of it comes."""
        if self._fresh and (_FENCE.match(line) or (not ended and line.strip() in ("", "`", "``", "~", "~~"))):
            if ended and line.strip():  # a fence opens or closes a code block; a line that may grow into one waits
                self._code = not self._code
            return "" if ended else line
        if self._code:
            return "" if ended else line  # a code line is left out once it has ended
        pieces = _CLAUSE_BREAK.split(line)
        rest = "" if ended else pieces.pop()
        for i, piece in enumerate(pieces):
            self._add(piece.strip(), ended and i == len(pieces) - 1, out)
        if pieces:
            self._fresh = False
        if self._held is not None and any(ch.isalnum() for ch in rest):
            out.append(self._held)  # a letter or digit follows: nothing more joins the held clause
            self._held = None
        return rest

    def _add(self, piece: str, ends_line: bool, out: list[Clause]) -> None:
        if not any(ch.isalnum() for ch in piece):
            if self._held is not None:
                text = f"{self._held.text} {piece}".strip()
                self._held = Clause(text, self._held.ends_sentence or ends_line or bool(_SENTENCE_END.search(text)))
            else:
                self._lead += piece + " "
            return
        if self._held is not None:
            out.append(self._held)
        text = f"{self._lead}{piece}"
        self._held, self._lead = Clause(text, ends_line or bool(_SENTENCE_END.search(text))), ""
