"""Batches: thousands of lines (texts, recordings, alignments) to animation, in parallel and resumable.

:func:`read_job` reads a manifest (CSV or JSONL) or a folder of inputs; :func:`run_batch`
writes each line's files to a folder of its own and an index of the run. ``vispeech batch``
is the command over them.
"""

from vispeech.batch.job import BatchLine, JobDefaults, read_job
from vispeech.batch.line import LineResult
from vispeech.batch.run import BatchReport, run_batch

__all__ = ["BatchLine", "BatchReport", "JobDefaults", "LineResult", "read_job", "run_batch"]
