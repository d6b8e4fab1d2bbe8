"""Edit distance between two sequences (Levenshtein) and the items one cheapest edit path keeps.

The phone error rate of recognised phones (:func:`vispeech.frontends.recognize.match_phones`)
and the word error rate of recognised text (:func:`vispeech.frontends.transcribe.word_error_rate`)
both count edits this way.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def edit_path(reference: Sequence, hypothesis: Sequence) -> tuple[int, list[tuple[int, int]]]:
    """The fewest substitutions, insertions and deletions that turn ``reference`` into
    ``hypothesis`` (items compared with ``==``), and the index pairs ``(i, j)`` with
    ``reference[i] == hypothesis[j]`` that one such cheapest path keeps, in order."""
    cost = np.zeros((len(reference) + 1, len(hypothesis) + 1), dtype=int)
    cost[:, 0], cost[0, :] = np.arange(len(reference) + 1), np.arange(len(hypothesis) + 1)
    for i, r in enumerate(reference, 1):
        for j, h in enumerate(hypothesis, 1):
            cost[i, j] = min(cost[i - 1, j] + 1, cost[i, j - 1] + 1, cost[i - 1, j - 1] + (r != h))
    pairs, i, j = [], len(reference), len(hypothesis)
    while i and j:
        same = reference[i - 1] == hypothesis[j - 1]
        if cost[i, j] == cost[i - 1, j - 1] + (not same):
            if same:
                pairs.append((i - 1, j - 1))
            i, j = i - 1, j - 1
        elif cost[i, j] == cost[i - 1, j] + 1:
            i -= 1
        else:
            j -= 1
    return int(cost[-1, -1]), pairs[::-1]
