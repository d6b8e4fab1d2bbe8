"""The self-contained preview page: audio plus a 2D face (jaw, lips, teeth, tongue) in one HTML file.

``face2d.js`` beside this module is a standalone browser script (global ``VispeechFace2D``)
that other front ends can reuse to draw the same face from ARKit weights.
"""

from vispeech.preview.page import render_preview, write_preview

__all__ = ["render_preview", "write_preview"]
