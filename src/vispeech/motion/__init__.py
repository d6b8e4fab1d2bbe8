"""The animation track, ARKit channel conventions, format readers/writers and retargeting."""
