"""Tracks onto rigs and heads: pose tables, rig space, output scales calibrated by a head's
geometry, and a head made ready to show the tracks (tongue targets, painted looks)."""
