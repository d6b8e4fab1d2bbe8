"""The one exception type vispeech raises for bad input, and its kind for native work that failed.

The CLI turns it into a one-line message and exit code 2; the server into a 4xx response.
:class:`UnshownChannelsWarning` says what of a track an output cannot carry.
"""


class VispeechError(ValueError):
    """Bad input or configuration, with a message fit to show a user as it is."""


class NativeFailure(VispeechError):
    """A native library crashed or ran past its time limit on this input, in a worker process of
    its own (:mod:`vispeech.frontends.isolation`): this input failed, everything else goes on.
    The server answers it with 422."""


class UnshownChannelsWarning(UserWarning):
    """A track has channels that the model it is written onto has no morph target for (left
    out of the file); the message names them."""
