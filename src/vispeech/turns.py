"""Turns for long work on a shared worker.

A long computation (ten minutes of uploaded audio through Whisper's encoder and a recurrent
network, tens of seconds on one core) calls :func:`give_turn` between its pieces. Where nobody
asked for turns (the CLI, the library, a batch) that does nothing. A server that runs many
clients' work on a few threads says what a turn does for the job it runs (:func:`taking_turns`;
:class:`vispeech.serve.pool.WorkPool` runs the short jobs that wait), so one request's long work
does not hold everyone else's for its whole length.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar

_turn: ContextVar[Callable[[], None] | None] = ContextVar("vispeech_turn", default=None)


def _forget() -> None:
    """In a process forked from a job that takes turns (a native worker started by it): the turn
    belongs to the parent's pool, whose copy here must never run the parent's queued jobs."""
    _turn.set(None)


os.register_at_fork(after_in_child=_forget)


def give_turn() -> None:
    """Let others' work run here now, if whoever runs this work asked for turns (else nothing)."""
    turn = _turn.get()
    if turn is not None:
        turn()


@contextmanager
def taking_turns(turn: Callable[[], None] | None) -> Iterator[None]:
    """Within the block, :func:`give_turn` calls ``turn`` (``None``: does nothing)."""
    token = _turn.set(turn)
    try:
        yield
    finally:
        _turn.reset(token)
