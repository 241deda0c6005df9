"""The textbook Viterbi recursion, the reference the dynamic programs of pivotd.pivot are tested against."""

from __future__ import annotations

import numpy as np


def viterbi_reference(val: np.ndarray, pen: np.ndarray) -> np.ndarray:
    """Best sequence (N,) of states maximising Σ val[i, s_i] + Σ pen[i − 1, s_i, s_{i−1}]: one fancy-indexed
    step per position, arithmetic in the order (pen + score) + val. val (N, K); pen (N − 1, K, K)."""
    N, K = val.shape
    back = np.zeros((N, K), dtype=int)
    score = val[0].copy()
    for i in range(1, N):
        tot = pen[i - 1] + score[None, :]
        back[i] = np.argmax(tot, axis=1)
        score = tot[np.arange(K), back[i]] + val[i]
    pick = [int(np.argmax(score))]
    for i in range(N - 1, 0, -1):
        pick.append(int(back[i, pick[-1]]))
    return np.array(pick[::-1])
