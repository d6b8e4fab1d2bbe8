"""A WebSocket connection of the server: counted against the caps, read into a queue and answered
one message at a time, the heavy parts in the service's pool; the server messages it sends."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading

from fastapi import WebSocket
from pydantic import BaseModel
from starlette.types import Message
from starlette.websockets import WebSocketDisconnect, WebSocketDisconnected

from vispeech.guards import client_key
from vispeech.serve.pool import Cancelled
from vispeech.serve.safety import NoSlot, Slot
from vispeech.serve.schemas import ErrorMessage, ServerMessage
from vispeech.serve.service import SpeechService

log = logging.getLogger("vispeech.serve")


def message_json(message: BaseModel | dict) -> str:
    """One server message (a model of :data:`~vispeech.serve.schemas.ServerMessage`, or the engine's
    dict form of one) as JSON."""
    typed = message if isinstance(message, BaseModel) else ServerMessage.validate_python(message)
    return typed.model_dump_json()


async def send_message(websocket: WebSocket, message: BaseModel | dict) -> None:
    """Send one server message (as :func:`message_json` writes it)."""
    await websocket.send_text(message_json(message))


async def send_error(websocket: WebSocket, message: str) -> None:
    """Tell the client what was wrong with its last message (an ``error`` message)."""
    await send_message(websocket, ErrorMessage(message=message))


GONE = (WebSocketDisconnect, WebSocketDisconnected, Cancelled)
"""What a connection's end raises: the client has gone."""


async def serve_connection(websocket: WebSocket, service: SpeechService, kind: type[Connection]) -> None:
    """One WebSocket connection of ``kind``: given a slot (or refused one), served, then freed."""
    await websocket.accept()
    connection = kind(websocket, service, client_key(websocket.scope))
    try:
        connection.slot = service.connections.open(connection.ip, connection.give_way)
    except NoSlot as exc:
        await connection._close(1013, str(exc))
        return
    try:
        await connection.serve()
    finally:
        service.connections.close(connection.slot)


GAVE_WAY = "the server is full and this connection was idle longest: it gave way to a new one (reconnect to go on)"
"""The error (and close reason, code 1013) of a connection that made room for a new one."""


class Connection:
    """A connection's reader (client messages into a queue, so a vanished client is seen at
    once) and processor (one message at a time, the heavy parts in the service's pool, each piece
    dropped unrun once the client has gone). Subclasses answer the messages (:meth:`_handle`)."""

    inbox_size = 4
    """Client messages read ahead of the one being answered (then TCP slows the client)."""
    kind: str
    """The kind of work its jobs are in the pool (:class:`~vispeech.serve.pool.FairQueue`)."""

    def __init__(self, websocket: WebSocket, service: SpeechService, ip: str) -> None:
        self.ws = websocket
        self.service = service
        self.config = service.config
        self.ip = ip
        self.cancelled = threading.Event()
        self.session = f"{id(self):x}"
        """What tells its jobs from those of its client's other connections in the pool."""
        self.evicted = False
        """Whether the connection gave its slot to a new one (it was idle longest)."""
        self._reader: asyncio.Task | None = None
        self.slot: Slot
        self.inbox: asyncio.Queue = asyncio.Queue(maxsize=self.inbox_size)

    def give_way(self) -> None:
        """Make room for a new connection: stop reading, so :meth:`serve` closes this one."""
        self.evicted = True
        if self._reader is not None:
            self._reader.cancel()

    async def serve(self) -> None:
        worker = asyncio.create_task(self._process())
        reader = self._reader = asyncio.create_task(self._read())
        try:
            done, _ = await asyncio.wait(
                {worker, reader}, timeout=self.config.stream_timeout, return_when=asyncio.FIRST_COMPLETED
            )
            self.cancelled.set()
            if worker not in done:
                worker.cancel()
                await asyncio.gather(worker, return_exceptions=True)
                if self.evicted:
                    await self._close(1013, GAVE_WAY)
                elif not done:
                    await self._close(
                        1001,
                        f"the connection was open {self.config.stream_timeout:g} s, the most "
                        "allowed: closing (open a new one to go on)",
                    )
        finally:
            self.cancelled.set()
            reader.cancel()
            worker.cancel()
            await asyncio.gather(worker, reader, return_exceptions=True)
            self._release()

    def _release(self) -> None:
        """Drop what the connection holds (it has ended)."""

    async def _read(self) -> None:
        while True:
            event = await self.ws.receive()
            if event["type"] == "websocket.disconnect":
                return
            await self._enqueue(event)

    async def _enqueue(self, event: Message) -> None:
        await self.inbox.put(event)

    async def _next(self) -> dict:
        """The next client message to answer."""
        return await self.inbox.get()

    async def _close(self, code: int, message: str) -> None:
        """Send ``message`` as an error, then close with ``code`` and the message as the reason."""
        with contextlib.suppress(*GONE, RuntimeError, OSError):
            await send_error(self.ws, message)
            await self.ws.close(code, message.encode()[:123].decode("utf-8", "ignore"))

    async def _run(self, fn, *args, weight: float = 0.0, kind: str | None = None):
        """``fn(*args)`` in the service's pool, a job of this connection's (a session of its
        client's) of ``kind`` (default: the connection's)."""
        return await self.service.pool.run(
            kind or self.kind, self.ip, fn, *args, cancelled=self.cancelled, weight=weight, session=self.session
        )

    def _worked(self) -> None:
        """The message just answered was valid work: the connection is not idle (nothing else
        keeps it open)."""
        self.service.connections.worked(self.slot)

    async def _process(self) -> None:
        timeout, slots = self.config.idle_timeout, self.service.connections
        try:
            while True:
                try:
                    event = await asyncio.wait_for(self._next(), max(0.0, timeout - slots.idle_for(self.slot)))
                except TimeoutError:
                    await self._close(1001, f"no valid message for {timeout:g} s: closing")
                    return
                self.slot.busy = True
                try:
                    if not await self._handle(event):
                        return
                finally:
                    self.slot.busy = False
        except GONE:
            pass
        except Exception:
            log.exception("internal error in a stream")
            await self._close(1011, "internal server error")

    async def _handle(self, event: dict) -> bool:
        """Answer one client message (:meth:`_worked` once it was valid work); ``False`` once the
        connection is closed."""
        raise NotImplementedError

    async def _oversize(self, event: dict) -> bool:
        """Close the connection (1009) when ``event`` is over the message size limit; whether it was."""
        limit = self.config.max_message_bytes
        raw = event.get("text")
        if raw is None:
            size = len(event.get("bytes") or b"")
        else:
            size = len(raw) if len(raw) > limit else len(raw.encode("utf-8", "replace"))
        if size <= limit:
            return False
        await self._close(1009, f"message too large (limit {limit} bytes)")
        return True
