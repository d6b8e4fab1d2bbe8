"""Post-processing of predicted tracks: closures, consonant overlays, jaw shift, ceilings."""
