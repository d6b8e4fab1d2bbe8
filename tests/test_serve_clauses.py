"""The text streams' clauses of many sessions voiced together in the native workers."""

from __future__ import annotations

import asyncio

import numpy as np

from vispeech.errors import NativeFailure
from vispeech.frontends import isolation
from vispeech.models.registry import load_model
from vispeech.serve.clauses import ClauseBatcher, _next_batch, _split, _Waiting
from vispeech.serve.pool import WorkPool
from vispeech.text_stream import SpeechTimeline, VoicedClause, voice_clauses

MARKER = "Chaosword"


def _waiting(text: str, first: bool, weight: float) -> _Waiting:
    clause = SpeechTimeline(load_model("baseline")).clause(text, "en")
    return _Waiting("baseline", clause if first else clause._replace(lead=0.0), weight, None)  # type: ignore[arg-type]


def test_a_batch_takes_first_clauses_before_later_ones_up_to_its_work():
    waiting = [
        _waiting("later one,", False, 0.02),
        _waiting("Hello,", True, 0.01),
        _waiting("later two,", False, 0.02),
        _waiting("Hi,", True, 0.01),
        _waiting("Hey,", True, 0.01),
    ]
    assert [w.clause.text for w in _next_batch(waiting, 0.035)] == ["Hello,", "Hi,", "Hey,"]
    assert [w.clause.text for w in _next_batch(waiting, 1.0)] == ["Hello,", "Hi,", "Hey,", "later one,", "later two,"]
    assert [w.clause.text for w in _next_batch(waiting[:1], 0.001)] == ["later one,"]  # at least one


def test_a_batch_is_split_into_parts_of_about_equal_work():
    assert _split([0, 1, 2, 3], [1.0] * 4, 2) == [[0, 1], [2, 3]]
    assert _split([0, 1, 2, 3], [3.0, 1.0, 1.0, 1.0], 2) == [[0], [1, 2, 3]]
    assert _split([5], [1.0], 2) == [[5]]
    assert _split([0, 1, 2], [1.0] * 3, 1) == [[0, 1, 2]]


def test_clauses_of_many_sessions_are_voiced_in_one_batch_and_a_crash_fails_its_own(monkeypatch):
    monkeypatch.setenv(isolation.FAULT_VARIABLE, f"crash:{MARKER}")
    isolation.set_workers(2)
    model = load_model("grid-tdnn-lowlatency")
    pool = WorkPool(1, 64)
    try:
        batcher = ClauseBatcher(pool, {"low": model}, "text", "text streams")
        texts = ["Hello,", f"Say {MARKER} now.", "Good morning!", "Hi there."]
        clauses = [SpeechTimeline(model).clause(text, "en") for text in texts]

        async def voice_all():
            return await asyncio.gather(
                *(batcher.voice("low", clause, 0.001) for clause in clauses), return_exceptions=True
            )

        voiced = asyncio.run(voice_all())
    finally:
        pool.close()
        isolation.set_workers(1)
    assert isinstance(voiced[1], NativeFailure) and str(voiced[1]) == "espeak-ng crashed on this text in language en"
    assert all(
        isinstance(one, VoicedClause) and one.text == text for one, text in zip(voiced, texts) if one is not voiced[1]
    )
    assert (batcher.batches, batcher.clauses, batcher.largest) == (1, 4, 4)


def test_a_fault_of_a_whole_batch_leaves_each_clause_its_own_try(monkeypatch):
    def broken(batch, models, workers):
        raise RuntimeError("a bug in batching")

    monkeypatch.setattr("vispeech.serve.clauses._voiced_in_workers", broken)
    model = load_model("grid-tdnn-lowlatency")
    pool = WorkPool(1, 64)
    try:
        batcher = ClauseBatcher(pool, {"low": model}, "text", "text streams")
        texts = ["Hello,", "Good morning!"]
        clauses = [SpeechTimeline(model).clause(text, "en") for text in texts]

        async def voice_all():
            return await asyncio.gather(*(batcher.voice("low", clause, 0.001) for clause in clauses))

        voiced = asyncio.run(voice_all())
    finally:
        pool.close()
    assert [one.text for one in voiced] == texts


def test_a_model_crosses_to_its_native_worker_once(monkeypatch):
    """Jobs name their model by its digest; its pickle goes only to a worker that lacks it."""
    models = {"low": load_model("grid-tdnn-lowlatency"), "base": load_model("baseline")}
    sent = []
    run_isolated_many = isolation.run_isolated_many

    def spy(library, what, fn, calls, limit=None):
        if fn.__name__ == "_voiced":  # not espeak-ng's own calls, run in place in a worker
            sent.extend(call[0].payload is not None for call in calls)
        return run_isolated_many(library, what, fn, calls, limit)

    monkeypatch.setattr(isolation, "run_isolated_many", spy)
    isolation.set_workers(1)  # with more, a pickle sent after a "not got it" may reach another worker
    pool = WorkPool(1, 64)
    try:
        batcher = ClauseBatcher(pool, models, "text", "text streams")
        texts = ["Hello,", "Good morning!", "Hi there.", "See you soon."]
        voiced = {}
        for name, model in models.items():
            for text in texts:  # one batch each
                clause = SpeechTimeline(model).clause(text, "en")
                voiced[name, text] = (asyncio.run(batcher.voice(name, clause, 0.001)), clause)
    finally:
        pool.close()
        isolation.set_workers(1)
    assert len(sent) - sum(sent) == 8 and sum(sent) <= 2  # 8 calls by digest; each model's pickle at most once
    for (name, text), (one, clause) in voiced.items():
        other = models["base" if name == "low" else "low"]
        own, others = (voice_clauses(m, [clause])[0].values for m in (models[name], other))
        assert one.text == text and np.abs(one.values - own).mean() < np.abs(one.values - others).mean()
