"""Track files: :mod:`~vispeech.motion.formats.registry` names every format once, with its
extensions, reader and writer; the modules beside it read and write each family of files."""
