"""vispeech: visual speech synthesis.

Text, time-aligned phones or audio in; lip, jaw and tongue animation (ARKit blend-shape
curves) out. The two types that carry everything are :class:`PhoneSequence` and
:class:`Track`.
"""

from vispeech.alignment.phones import Phone, PhoneSequence, Word
from vispeech.errors import VispeechError
from vispeech.motion.track import Track

__all__ = ["Phone", "PhoneSequence", "Track", "VispeechError", "Word"]
__version__ = "0.1.0"
