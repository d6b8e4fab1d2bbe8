"""The text streams' clauses of every session, voiced together in the native worker processes."""

from __future__ import annotations

import asyncio
import hashlib
import pickle
import threading
from collections.abc import Mapping, Sequence
from typing import NamedTuple

from vispeech.errors import NativeFailure, VispeechError
from vispeech.frontends import isolation
from vispeech.frontends.espeak import find_language
from vispeech.models.contract import Estimator
from vispeech.serve.pool import WorkPool
from vispeech.text_stream import Clause, VoicedClause, voice_clauses

BATCH_SECONDS = 0.05
"""Estimated worker seconds of clauses a batch holds for each native worker (at least one
clause): a new stream's first clause waits for no more than about that much before its turn."""


class _Model(NamedTuple):
    """A model as a native worker's job names it: ``key``, the digest of its pickle, and the
    pickle itself (``payload``) only when the worker has not got it yet (:func:`_voiced`)."""

    key: str
    payload: bytes | None = None

    @classmethod
    def of(cls, model: Estimator) -> _Model:
        payload = pickle.dumps(model, protocol=pickle.HIGHEST_PROTOCOL)
        return cls(hashlib.blake2b(payload, digest_size=16).hexdigest(), payload)

    @property
    def named(self) -> _Model:
        """The model by its key alone."""
        return _Model(self.key)


class _Waiting(NamedTuple):
    """A session's clause waiting: the name of its model, the clause, its estimated work
    (seconds) and the future of its voice."""

    model: str
    clause: Clause
    weight: float
    future: asyncio.Future


class ClauseBatcher:
    """Text stream clauses of every session, voiced in batches: one pool job (of ``kind``, on
    behalf of ``key``) at a time takes the clauses waiting, every session's first clause before
    any later one, up to :data:`BATCH_SECONDS` of estimated work for each native worker, and
    voices them (:func:`~vispeech.text_stream.voice_clauses`: espeak-ng and the model) in the
    native worker processes (:mod:`vispeech.frontends.isolation`),
    split between them so that every core speaks, the clauses of a model in each one call of the
    model. The event loop's process only puts each voiced clause on its
    stream's timeline and sends it. A model crosses to the native workers rarely: a job names it
    by its digest, and is sent again with the pickle (1.9 MB for ``grid-tdnn-lowlatency``) when
    its worker answers that it has not got it; whichever worker takes that job keeps the model.

    A worker that crashes or hangs on its part of a batch costs that part one more try, each of
    its clauses alone: only the clause it crashes or hangs on fails. ``batches`` and ``clauses``
    count what it ran, ``largest`` is the most clauses one batch held.
    """

    def __init__(self, pool: WorkPool, models: Mapping[str, Estimator], kind: str, key: str) -> None:
        self.pool, self.models, self.kind, self.key = pool, models, kind, key
        self._pickled: dict[str, _Model] = {}  # model name → its pickle, made on first use
        self._pickling = threading.Lock()
        self._waiting: list[_Waiting] = []
        self._lock = threading.Lock()  # the waiting list is taken in a worker thread
        self._busy = False  # a job is in the pool
        self.batches = self.clauses = self.largest = 0

    async def voice(self, model: str, clause: Clause, weight: float) -> VoicedClause:
        """``clause`` spoken and animated by the model named ``model`` (one of those given);
        :class:`~vispeech.errors.VispeechError` when it cannot be said."""
        future = asyncio.get_running_loop().create_future()
        with self._lock:
            self._waiting.append(_Waiting(model, clause, weight, future))
        if not self._busy:
            self._busy = True
            asyncio.ensure_future(self._run())
        return await future

    def warm_up(self, model: str, clause: Clause) -> None:
        """Voice ``clause`` a few times in each native worker, so a first stream is no slower."""
        calls = [(self._pickle(model), [clause])] * (2 * isolation.workers())
        isolation.run_isolated_many("espeak-ng", "a greeting", _voiced, calls)

    def _pickle(self, model: str) -> _Model:
        """The model named ``model`` as jobs carry it (pickled once)."""
        with self._pickling:
            if model not in self._pickled:
                self._pickled[model] = _Model.of(self.models[model])
            return self._pickled[model]

    async def _run(self) -> None:
        while True:
            with self._lock:
                weight = sum(waiting.weight for waiting in self._waiting)
            try:
                batch, results = await self.pool.run(self.kind, self.key, self._voice, weight=weight)
            except BaseException as exc:  # Busy, shutting down: every session waiting is told
                with self._lock:
                    batch, self._waiting = self._waiting, []
                results = [exc] * len(batch)
            self.batches += 1
            self.clauses += len(batch)
            self.largest = max(self.largest, len(batch))
            for waiting, result in zip(batch, results):
                if waiting.future.done():
                    continue
                if isinstance(result, BaseException):
                    waiting.future.set_exception(result)
                else:
                    waiting.future.set_result(result)
            with self._lock:
                if not self._waiting:
                    self._busy = False
                    return

    def _voice(self) -> tuple[list[_Waiting], list[VoicedClause | BaseException]]:
        """In a pool thread: the clauses of the next batch, and each one's voice or error."""
        workers = isolation.workers()
        with self._lock:
            waiting = [entry for entry in self._waiting if not entry.future.done()]  # their sessions went away
            batch = _next_batch(waiting, BATCH_SECONDS * workers)
            taken = {id(entry) for entry in batch}
            self._waiting = [entry for entry in waiting if id(entry) not in taken]
        models = {name: self._pickle(name) for name in {entry.model for entry in batch}}
        try:
            return batch, _voiced_in_workers(batch, models, workers)
        except Exception:  # noqa: BLE001 (a fault of the batch: each clause is tried alone, so only its own fails)
            return batch, [_tried_alone(entry, models[entry.model]) for entry in batch]


def _next_batch(waiting: list[_Waiting], budget: float) -> list[_Waiting]:
    """The clauses of the next batch: first clauses (those that begin a stream) before later ones,
    in the order they came, up to ``budget`` seconds of estimated work (at least one)."""
    batch: list[_Waiting] = []
    work = 0.0
    for entry in sorted(waiting, key=lambda entry: entry.clause.lead == 0):  # stable: in order within each
        if batch and work + entry.weight > budget:
            break
        batch.append(entry)
        work += entry.weight
    return batch


def _voiced_in_workers(
    batch: Sequence[_Waiting], models: Mapping[str, _Model], workers: int
) -> list[VoicedClause | BaseException]:
    """Each clause of ``batch`` voiced in a native worker: the clauses of each model in up to
    ``workers`` parts of about equal work, sent at once; a part whose worker crashes or hangs
    tried again clause by clause."""
    parts: list[list[int]] = []
    for name in dict.fromkeys(entry.model for entry in batch):
        members = [k for k, entry in enumerate(batch) if entry.model == name]
        parts += _split(members, [batch[k].weight for k in members], workers)
    limit = min(isolation.TIME_LIMIT, 1.0 + 10 * max(sum(batch[k].weight for k in part) for part in parts))
    calls = [(models[batch[part[0]].model], [batch[k].clause for k in part]) for part in parts]
    out: list[VoicedClause | BaseException] = [NativeFailure("unvoiced")] * len(batch)
    for part, voiced in zip(parts, _run_voiced("a batch", calls, limit)):
        if isinstance(voiced, NativeFailure):
            voiced = [_voiced_alone(batch[k], models[batch[k].model]) for k in part]
        for k, result in zip(part, voiced):
            out[k] = result
    return out


def _voiced_alone(entry: _Waiting, model: _Model) -> VoicedClause | VispeechError:
    """One clause voiced in a worker of its own: its :class:`~vispeech.errors.NativeFailure` if
    espeak-ng crashes or hangs on it."""
    what = f"this text in language {find_language(entry.clause.language).code}"
    voiced = _run_voiced(what, [(model, [entry.clause])])[0]
    return voiced if isinstance(voiced, NativeFailure) else voiced[0]


def _tried_alone(entry: _Waiting, model: _Model) -> VoicedClause | BaseException:
    """One clause voiced alone, or the exception that stopped it."""
    try:
        return _voiced_alone(entry, model)
    except Exception as exc:  # noqa: BLE001 (given to its session alone)
        return exc


def _split(members: list[int], weights: list[float], parts: int) -> list[list[int]]:
    """``members`` in up to ``parts`` consecutive groups of about equal summed ``weights``."""
    total, work = sum(weights), 0.0
    groups: list[list[int]] = [[]]
    for member, weight in zip(members, weights):
        if groups[-1] and len(groups) < parts and work >= total * len(groups) / parts:
            groups.append([])
        groups[-1].append(member)
        work += weight
    return groups


def _run_voiced(
    what: str, calls: list[tuple[_Model, list[Clause]]], limit: float | None = None
) -> list[list[VoicedClause | VispeechError] | NativeFailure]:
    """:func:`_voiced` for each call in the native workers, named models (:attr:`_Model.named`)
    first, and again with the model's pickle for a call whose worker has not got it."""
    results = isolation.run_isolated_many(
        "espeak-ng", what, _voiced, [(model.named, clauses) for model, clauses in calls], limit
    )
    lacking = [k for k, result in enumerate(results) if result is None]
    if lacking:
        sent = isolation.run_isolated_many("espeak-ng", what, _voiced, [calls[k] for k in lacking], limit)
        for k, result in zip(lacking, sent):
            results[k] = result
    return results  # type: ignore[return-value]  # a call with the model's pickle never returns None


_received: dict[str, Estimator] = {}
"""In a native worker: the models it has been sent, by :attr:`_Model.key`."""


def _voiced(model: _Model, clauses: list[Clause]) -> list[VoicedClause | VispeechError] | None:
    """In a native worker: :func:`~vispeech.text_stream.voice_clauses` by ``model``; ``None``
    when the worker has not got the model and the job carries only its key."""
    if model.key not in _received:
        if model.payload is None:
            return None
        _received[model.key] = pickle.loads(model.payload)
    return voice_clauses(_received[model.key], clauses)
