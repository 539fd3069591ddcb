"""Mask evaluation against ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from slzcli.evaluate.safety import mask_counts, precision_recall_curve, total


def test_counts_by_hand() -> None:
    truth = np.array([[1, 1, 0, 0]], bool)
    pred = np.array([[1, 0, 1, 0]], bool)
    c = mask_counts(pred, truth)
    assert (c.tp, c.fp, c.fn, c.tn) == (1, 1, 1, 1)
    assert c.precision == 0.5 and c.recall == 0.5 and c.iou == pytest.approx(1 / 3)


def test_unknown_pixels_are_ignored_and_totals_are_micro_averaged() -> None:
    truth = np.array([[1, 1, 0, 0]], bool)
    pred = np.array([[1, 1, 1, 1]], bool)
    known = np.array([[1, 1, 1, 0]], bool)
    c = mask_counts(pred, truth, known)
    assert (c.tp, c.fp, c.fn, c.tn) == (2, 1, 0, 0)
    both = total([c, mask_counts(~pred, truth)])
    assert both.tp == 2 and both.fn == 2 and both.precision == pytest.approx(2 / 3)


def test_nothing_predicted_gives_undefined_precision() -> None:
    c = mask_counts(np.zeros((2, 2), bool), np.ones((2, 2), bool))
    assert c.precision is None and c.recall == 0.0


def test_pr_curve_matches_direct_counts() -> None:
    rng = np.random.default_rng(0)
    score = rng.random((40, 50))
    truth = score + rng.normal(0, 0.2, score.shape) > 0.5
    taus = np.array([0.9, 0.1, 0.5, 0.3])
    precision, recall = precision_recall_curve(score, truth, taus)
    for tau, p, r in zip(taus, precision, recall, strict=True):
        c = mask_counts(score > tau, truth)
        assert p == pytest.approx(c.precision) and r == pytest.approx(c.recall)
