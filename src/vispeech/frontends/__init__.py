"""Front ends: text to phones and audio (espeak-ng); audio and text to phones (alignment)."""
