"""The one exception type vispeech raises for bad input.

The CLI turns it into a one-line message and exit code 2; the server into a 4xx response.
"""


class VispeechError(ValueError):
    """Bad input or configuration, with a message fit to show a user as it is."""
