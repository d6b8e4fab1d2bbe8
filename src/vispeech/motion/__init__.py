"""Animation tracks: the :class:`~vispeech.motion.track.Track` core with ARKit names and ease
curves; track files (:mod:`~vispeech.motion.formats`); tracks onto rigs and heads
(:mod:`~vispeech.motion.rigging`); non-verbal layers (:mod:`~vispeech.motion.life`)."""
