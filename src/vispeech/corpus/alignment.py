"""Phones for a whole corpus by forced alignment, cached per utterance."""

from __future__ import annotations

import hashlib
import os
import re
import warnings

from vispeech.alignment.phones import PhoneSequence
from vispeech.corpus.cache import CorpusCache
from vispeech.corpus.corpus import Corpus, CorpusWarning
from vispeech.errors import VispeechError
from vispeech.frontends.align import ALIGNER, align
from vispeech.frontends.audio import read_audio

_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def align_corpus(
    corpus: Corpus,
    cache: CorpusCache | str | os.PathLike | None = None,
    *,
    jobs: int = 1,
    progress: bool = True,
    strict: bool = False,
) -> Corpus:
    """Give every utterance without phones its forced alignment (:func:`vispeech.frontends.align.align`).

    Results are read from and written to ``cache`` (a :class:`CorpusCache` or a folder;
    default ``corpus.cache``; each entry remembers the transcript, the language and the aligner, so
    a changed transcript or language is aligned again). ``jobs`` > 1 aligns in that many processes; ``progress``
    shows a tqdm bar on stderr. An utterance that fails to align keeps ``phones=None`` and is
    named in a :class:`~vispeech.corpus.corpus.CorpusWarning` (and ``corpus.problems``), or
    raises :class:`VispeechError` if ``strict``. Returns ``corpus``, updated in place.
    """
    from tqdm import tqdm

    if cache is not None and not isinstance(cache, CorpusCache):
        cache = CorpusCache(cache)
    store = cache if cache is not None else corpus.cache
    todo = []
    for utterance in corpus:
        if utterance.phones is not None:
            continue
        cached = store.read_json(cache_key(utterance.id)) if store is not None else None
        if (
            isinstance(cached, dict)
            and cached.get("aligner") == ALIGNER
            and cached.get("text") == utterance.text
            and cached.get("language") == corpus.language
        ):
            utterance.phones = PhoneSequence.from_dict(cached["phones"])
        else:
            todo.append(utterance)
    if not todo:
        return corpus

    tasks = [(str(u.audio_path), u.text, corpus.language) for u in todo]
    bar = tqdm(total=len(tasks), desc=f"aligning {corpus.name}", unit="utt", disable=not progress)
    try:
        if jobs > 1:
            import multiprocessing

            with multiprocessing.get_context("spawn").Pool(jobs) as pool:
                results = _collect(pool.imap(_align_file, tasks, chunksize=8), bar)
        else:
            results = _collect(map(_align_file, tasks), bar)
    finally:
        bar.close()

    for utterance, (phones, error) in zip(todo, results, strict=True):
        if error is not None:
            message = f"cannot align {utterance.id}: {error}"
            if strict:
                raise VispeechError(message)
            warnings.warn(message, CorpusWarning, stacklevel=2)
            corpus.problems.append(message)
            continue
        utterance.phones = PhoneSequence.from_dict(phones)
        if store is not None:
            entry = {"aligner": ALIGNER, "text": utterance.text, "language": corpus.language, "phones": phones}
            store.write_json(cache_key(utterance.id), entry)
    return corpus


def cache_key(utterance_id: str) -> str:
    """The cache key of an utterance's alignment: ``align/<id>`` (unsafe characters replaced, plus a hash)."""
    safe = _UNSAFE.sub("_", utterance_id)
    if safe != utterance_id or safe.startswith("."):
        safe = f"{safe.lstrip('.')}-{hashlib.sha1(utterance_id.encode('utf-8')).hexdigest()[:8]}"
    return f"align/{safe}"


def _collect(results, bar) -> list:
    collected = []
    for result in results:
        collected.append(result)
        bar.update(1)
    return collected


def _align_file(task: tuple[str, str, str]) -> tuple[dict | None, str | None]:
    """Align one audio file; ``(phone sequence as dict, None)`` or ``(None, error message)``."""
    path, text, language = task
    try:
        samples, sample_rate = read_audio(path)
        return align(samples, sample_rate, text, language).to_dict(), None
    except VispeechError as exc:
        return None, str(exc)
