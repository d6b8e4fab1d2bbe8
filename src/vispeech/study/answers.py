"""The answers of a study: its tasks, what each task's answer is, and the columns of
``answers.csv`` (written by :meth:`vispeech.study.store.StudyStore.export`, read by
:func:`vispeech.study.analysis.read_answers`; docs/study.md describes them)."""

TASKS = ("rating", "pairwise")
RATINGS = tuple(range(1, 10))
"""The answers of a rating: 1 (worst) to 9 (best)."""
PAIRWISE_ANSWERS = ("left", "tie", "right")
"""The answers of a pairwise trial."""
ANSWER_COLUMNS = (
    "participant",
    "task",
    "trial",
    "sentence",
    "audio",
    "warmup",
    "check",
    "position",
    "model",
    "left",
    "right",
    "answer",
    "ms",
    "answered_at",
    "expected",
)
"""The columns of ``answers.csv``: one row per answer, one per face on a rating trial."""
