"""The Bayesian baseline (BASELINE.md): naive Bayes fusion of the four maps in log-odds.

Each map is read as P(safe | cue_i), clipped to [eps, 1 - eps] so that no single cue is
certain. With prior pi the cues combine as
``logit P(safe | all) = logit(pi) + sum_i (logit(m_i) - logit(pi))``;
with pi = 0.5 this is ``prod(m) / (prod(m) + prod(1 - m))``. A reconstruction of [16]
(Chatzikalymnios & Moustakas 2022), whose exact formula is not public.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

FLOAT32_EPS_MIN = 1e-6  # below this 1 - eps rounds to 1 in float32 (ulp 6e-8): compute in float64


def logit(p: float | np.ndarray) -> float | np.ndarray:
    return np.log(p) - np.log1p(-p)


def fuse(maps: list[np.ndarray], prior: float, eps: float) -> np.ndarray:
    """P(safe | all cues), float32 of the maps' shape.

    float32 arithmetic while 1 - eps is representable in it (eps >= FLOAT32_EPS_MIN), else float64.
    """
    dtype = np.float32 if eps >= FLOAT32_EPS_MIN else np.float64
    prior_logit = float(logit(prior))
    total = np.full(np.shape(maps[0]), prior_logit, dtype)
    for m in maps:
        p = np.clip(np.asarray(m, dtype), eps, 1.0 - eps)
        total += np.log(p / (1.0 - p))
        total -= prior_logit
    return expit(total).astype(np.float32, copy=False)
