"""Rebuild the packaged default vocabulary slzcli/slam/data/slz_orb_k10_L3.txt (and time it).

Training data: 30 frames of two analytic rendered flights (tests/slam_flight.py, seeds 11
and 12, not the seed the tests fly over) and the 10 real RealSense frames in
../shared/data/realsense_floor. k, L, iterations and seed from configs/default.yaml (slam.vocab).
Usage: .venv/bin/python scripts/build_default_vocabulary.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))

import slam_flight  # noqa: E402

from slzcli.config import load_config  # noqa: E402
from slzcli.outputs.files import write_text  # noqa: E402
from slzcli.slam.features import detect, make_orb  # noqa: E402
from slzcli.slam.vocabulary import DEFAULT_VOCABULARY, read_vocabulary, train_vocabulary, vocabulary_text  # noqa: E402

REALSENSE = REPO.parent / "shared" / "data" / "realsense_floor" / "color"


def main() -> None:
    cfg = load_config().slam
    orb = make_orb(cfg.orb.n_features, cfg.orb.n_levels, cfg.orb.scale_factor, cfg.orb.fast_threshold)
    t0 = time.perf_counter()
    docs = []
    for seed in (11, 12):
        frames, _ = slam_flight.render_flight(15, seed=seed, width=640, height=480)
        docs += [detect(orb, f.rgb)[1] for f in frames]
    for p in sorted(REALSENSE.glob("*.png")):
        bgr = cv2.imread(str(p))
        if bgr is None:
            raise FileNotFoundError(f"{p}: not an image OpenCV reads")
        docs.append(detect(orb, cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))[1])
    t1 = time.perf_counter()
    vocab = train_vocabulary(docs, cfg.vocab.k, cfg.vocab.levels, cfg.vocab.iterations, cfg.vocab.seed)
    t2 = time.perf_counter()
    write_text(DEFAULT_VOCABULARY, vocabulary_text(vocab))
    read_vocabulary(DEFAULT_VOCABULARY)
    print(f"{DEFAULT_VOCABULARY.name}: {len(docs)} images, {sum(len(d) for d in docs)} descriptors, "
          f"{vocab.n_words} words, {vocab.n_nodes} nodes, {DEFAULT_VOCABULARY.stat().st_size} bytes; "
          f"features {t1 - t0:.1f} s (incl. rendering), training {t2 - t1:.2f} s")


if __name__ == "__main__":
    main()
