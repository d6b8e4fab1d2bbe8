"""What of a text is spoken: chat-model replies carry Markdown, links and emoji that a voice
must not read out ("slightly smiling face", "asterisk asterisk", "h t t p s colon ...").

:func:`speakable` parses the text as CommonMark (markdown-it-py) and keeps the words of its
paragraphs, headings, list items and quotes (emphasis marks dropped, a link's text kept, its
address not, inline code kept as words), leaves out code blocks, HTML and images, drops bare
``http(s)://`` and ``www.`` addresses, and removes every emoji (the ``emoji`` package's list,
skin tones and joiners included). Blocks that end without punctuation get a full stop, so a
list is read as a list. Plain text comes back as it was, but for white space runs folded to
one space.
"""

from __future__ import annotations

import re
from functools import cache

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
