"""The vispeech web server (FastAPI): speak, chat and stream APIs over the library.

Start it with ``vispeech serve`` or ``uvicorn`` on :func:`create_app`; ``docs/serve.md``
describes the routes, the stream protocol and the limits.
"""

from vispeech.serve.app import create_app
from vispeech.serve.bot import ChatBot, ChatBotError, ChatBotTimeout, ChatModel, ChatTurn, RuleBot
from vispeech.serve.cache import CacheKey, UtteranceCache, default_cache_path
from vispeech.serve.config import ServeConfig
from vispeech.serve.llm import OpenAIChatBot
from vispeech.serve.service import SpeechService
from vispeech.serve.sessions import ChatSessions, UnknownSession
from vispeech.streaming import PhoneStream, open_phone_stream
from vispeech.text_stream import speech_messages, split_clauses

__all__ = [
    "CacheKey",
    "ChatBot",
    "ChatBotError",
    "ChatBotTimeout",
    "ChatModel",
    "ChatSessions",
    "ChatTurn",
    "OpenAIChatBot",
    "PhoneStream",
    "RuleBot",
    "ServeConfig",
    "SpeechService",
    "UnknownSession",
    "UtteranceCache",
    "create_app",
    "default_cache_path",
    "open_phone_stream",
    "speech_messages",
    "split_clauses",
]
