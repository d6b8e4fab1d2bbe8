"""Control models: phones + fps to an animation track."""
