"""What of a text is spoken: chat-model replies carry Markdown, links and emoji that a voice
must not read out ("slightly smiling face", "asterisk asterisk", "h t t p s colon ...").

:func:`speakable` parses the text as CommonMark (markdown-it-py) and keeps the words of its
paragraphs, headings, list items and quotes (emphasis marks dropped, a link's text kept, its
address not, inline code kept as words), leaves out code blocks, HTML and images, drops bare
``http(s)://`` and ``www.`` addresses, and removes every emoji (the ``emoji`` package's list,
skin tones and joiners included). Blocks that end without punctuation get a full stop, so a
list is read as a list. Plain text comes back as it was, but for white space runs folded to
one space. :func:`detect_language` tells which of some languages a text is written in.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import cache

from vispeech.errors import VispeechError

_URL = re.compile(r"(?:\bhttps?://|\bwww\.)\S*[^\s.,;:!?)\]'\"”’]", re.IGNORECASE)
_SPACE = re.compile(r"\s+")
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
    for token in _parser().parse(text):
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
