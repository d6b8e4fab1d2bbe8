"""The time-aligned phone sequence and the alignment file formats."""
