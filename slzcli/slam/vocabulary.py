"""A DBoW2 ORB vocabulary: train one (hierarchical k-majority), write and validate its text form.

ORB-SLAM3 needs a bag-of-words vocabulary; the official ORBvoc.txt is a 139 MB download,
so slz trains small ones from recordings (``slz vocab build``) and ships a default.
Text format (DBoW2 / ORB_SLAM3 ``TemplatedVocabulary::loadFromTextFile``): a header line
``k L scoring weighting``, then one line per node after the root, in an order where every
parent precedes its children: ``parent isLeaf d0 ... d31 weight`` (d = descriptor bytes).
The native loader trusts the file completely (a bad parent id or a childless inner node
is a segfault later), so ``parse_vocabulary`` checks everything it relies on.
"""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slzcli.bounds import MAX_VOCABULARY_BYTES, read_regular
from slzcli.errors import DatasetError
from slzcli.outputs import safe_output
from slzcli.outputs.files import write_text
from slzcli.slam.features import detect, make_orb
from slzcli.sources import open_recording
from slzcli.types import Frame

if TYPE_CHECKING:
    from slzcli.config import Config, OrbCfg

log = logging.getLogger(__name__)

DESCRIPTOR_BYTES = 32
SCORING_L1 = 0      # DBoW2 ScoringType L1_NORM (what ORBvoc.txt uses)
WEIGHTING_TF_IDF = 0  # DBoW2 WeightingType TF_IDF (what ORBvoc.txt uses)
# Header ranges the native loader accepts (DBoW2 loadFromTextFile).
MAX_K, MAX_L, MAX_SCORING, MAX_WEIGHTING = 20, 10, 5, 3
# Shipped with the package; how it was made: data/README.md.
DEFAULT_VOCABULARY = Path(__file__).resolve().parent / "data" / "slz_orb_k10_L3.txt"


@dataclass(frozen=True, eq=False)
class Vocabulary:
    """A vocabulary tree; node 0 is the root. Arrays are indexed by node id."""

    k: int
    levels: int
    parents: np.ndarray      # (n,) int64, -1 for the root
    is_leaf: np.ndarray      # (n,) bool
    descriptors: np.ndarray  # (n, 32) uint8 (root: zeros)
    weights: np.ndarray      # (n,) float64 (IDF on leaves, 0 on inner nodes)
    scoring: int = SCORING_L1
    weighting: int = WEIGHTING_TF_IDF

    @property
    def n_nodes(self) -> int:
        return int(self.parents.shape[0])

    @property
    def n_words(self) -> int:
        return int(self.is_leaf.sum())

    def children(self) -> list[np.ndarray]:
        order = np.argsort(self.parents[1:], kind="stable") + 1
        counts = np.bincount(self.parents[1:], minlength=self.n_nodes)
        return np.split(order, np.cumsum(counts)[:-1])

    def transform(self, desc: np.ndarray) -> np.ndarray:
        """Word (leaf node id) of each descriptor, descending greedily like DBoW2."""
        bits = _bits(desc)
        node_bits = _bits(self.descriptors)
        kids = self.children()
        current = np.zeros(len(desc), np.int64)
        for _ in range(self.levels + 1):
            active = ~self.is_leaf[current]
            if not active.any():
                break
            for node in np.unique(current[active]):
                sel = np.flatnonzero(current == node)
                ch = kids[node]
                d = _hamming(bits[sel], node_bits[ch])
                current[sel] = ch[np.argmin(d, axis=1)]
        return current


def _bits(desc: np.ndarray) -> np.ndarray:
    return np.unpackbits(np.ascontiguousarray(desc, dtype=np.uint8), axis=1).astype(np.float32)


def _hamming(a_bits: np.ndarray, b_bits: np.ndarray) -> np.ndarray:
    """Pairwise Hamming distances of unpacked bit rows, as two matrix products."""
    return a_bits @ (1.0 - b_bits).T + (1.0 - a_bits) @ b_bits.T


def _k_majority(bits: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """k-majority clustering of binary rows (k-means++ seeding, bitwise-majority centres)."""
    n = bits.shape[0]
    centres = [bits[rng.integers(n)]]
    dmin = _hamming(bits, centres[0][None])[:, 0]
    for _ in range(1, k):
        p = dmin ** 2
        if p.sum() <= 0:
            break
        c = bits[rng.choice(n, p=p / p.sum())]
        centres.append(c)
        dmin = np.minimum(dmin, _hamming(bits, c[None])[:, 0])
    C = np.stack(centres)
    labels = np.full(n, -1)
    for _ in range(iterations):
        new = np.argmin(_hamming(bits, C), axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
        counts = np.bincount(labels, minlength=len(C)).astype(np.float32)
        sums = np.zeros_like(C)
        np.add.at(sums, labels, bits)
        keep = counts > 0
        C = (sums[keep] >= (counts[keep, None] / 2.0)).astype(np.float32)
        labels = np.argmin(_hamming(bits, C), axis=1)
    return C, labels


def train_vocabulary(documents: Sequence[np.ndarray], k: int, levels: int, iterations: int = 10,
                     seed: int = 0) -> Vocabulary:
    """Hierarchical k-majority over the documents' ORB descriptors; TF-IDF leaf weights.

    ``documents``: one (N_i, 32) uint8 array per image. IDF = log((D + 1) / n_w) with D the
    number of documents and n_w those containing word w, so every leaf weight is positive
    (a zero weight makes ORB-SLAM3's BoW matching starve and tracking fail silently).
    """
    docs = [np.asarray(d, np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in documents]
    all_desc = np.concatenate(docs) if docs else np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    if len(all_desc) < k:
        raise ValueError(f"need at least k={k} descriptors to train, got {len(all_desc)}")
    rng = np.random.default_rng(seed)
    bits = _bits(all_desc)
    parents, leaf, node_desc = [-1], [False], [np.zeros(256, np.float32)]
    queue: list[tuple[int, np.ndarray, int]] = [(0, np.arange(len(bits)), 0)]
    head = 0
    while head < len(queue):  # breadth first: parents always precede their children
        node, members, level = queue[head]
        head += 1
        if len(members) <= k:
            centres, labels = bits[members], np.arange(len(members))
        else:
            centres, labels = _k_majority(bits[members], k, iterations, rng)
        for c in range(len(centres)):
            sub = members[labels == c]
            nid = len(parents)
            parents.append(node)
            node_desc.append(centres[c])
            is_leaf = level + 1 >= levels or len(sub) <= 1
            leaf.append(is_leaf)
            if not is_leaf:
                queue.append((nid, sub, level + 1))
    parents_a = np.array(parents, np.int64)
    leaf_a = np.array(leaf, bool)
    desc_a = np.packbits(np.stack(node_desc).astype(np.uint8), axis=1)
    vocab = Vocabulary(k, levels, parents_a, leaf_a, desc_a, np.zeros(len(parents_a)))
    words_per_doc = [np.unique(vocab.transform(d)) for d in docs if len(d)]
    n_w = np.bincount(np.concatenate(words_per_doc), minlength=vocab.n_nodes) if words_per_doc else \
        np.zeros(vocab.n_nodes)
    weights = np.where(leaf_a, np.log((len(docs) + 1.0) / np.maximum(n_w, 1)), 0.0)
    return Vocabulary(k, levels, parents_a, leaf_a, desc_a, weights)


def vocabulary_text(vocab: Vocabulary) -> str:
    """The DBoW2 text form. No trailing newline: the native loader turns an empty last line into a
    childless inner node, which crashes the first lookup that reaches it."""
    lines = [f"{vocab.k} {vocab.levels} {vocab.scoring} {vocab.weighting}"]
    for nid in range(1, vocab.n_nodes):
        d = " ".join(map(str, vocab.descriptors[nid].tolist()))
        lines.append(f"{vocab.parents[nid]} {int(vocab.is_leaf[nid])} {d} {vocab.weights[nid]:.6g}")
    return "\n".join(lines)


def parse_vocabulary(text: str, source: str) -> Vocabulary:
    """Parse and check a DBoW2 text vocabulary; DatasetError(source, what is wrong) otherwise.

    Checks what the native loader assumes: header ranges, one line per node with 35 fields,
    parents that exist and precede, descriptor bytes in 0..255, every inner node with a child,
    finite weights and positive leaf weights.
    """
    text = text.rstrip("\n")
    head_line, _, body_text = text.partition("\n")
    if not head_line.strip():
        raise DatasetError(source, "vocabulary is empty")
    head = head_line.split()
    try:
        k, L, scoring, weighting = (int(v) for v in head)
    except ValueError:
        raise DatasetError(source, f"vocabulary header must be 'k L scoring weighting' (4 integers), "
                                   f"got {head_line[:60]!r}") from None
    if not (2 <= k <= MAX_K and 1 <= L <= MAX_L and 0 <= scoring <= MAX_SCORING and 0 <= weighting <= MAX_WEIGHTING):
        raise DatasetError(source, f"vocabulary header out of range (k 2..{MAX_K}, L 1..{MAX_L}, scoring "
                                   f"0..{MAX_SCORING}, weighting 0..{MAX_WEIGHTING}): {head_line[:60]!r}")
    if not body_text.strip():
        raise DatasetError(source, "vocabulary has a header but no nodes")
    n_lines = body_text.count("\n") + 1
    max_nodes = (k ** (L + 1) - 1) // (k - 1)
    if n_lines + 1 > max_nodes:
        raise DatasetError(source, f"vocabulary has {n_lines + 1} nodes, more than k={k}, L={L} allow ({max_nodes})")
    table = _numeric_table(body_text, n_lines, source)
    ints_f = table[:, :-1]
    if np.any(ints_f != np.round(ints_f)):
        i = int(np.flatnonzero((ints_f != np.round(ints_f)).any(axis=1))[0])
        raise DatasetError(source, f"vocabulary line {i + 2}: parent, isLeaf and descriptor bytes must be integers")
    ints = ints_f.astype(np.int64)
    weights = table[:, -1]
    parents = np.concatenate([[-1], ints[:, 0]])
    leaf_flag = ints[:, 1]
    desc = ints[:, 2:]
    ids = np.arange(1, len(parents))
    if np.any(parents[1:] < 0) or np.any(parents[1:] >= ids):
        i = int(np.flatnonzero((parents[1:] < 0) | (parents[1:] >= ids))[0])
        raise DatasetError(source, f"vocabulary line {i + 2}: parent {parents[i + 1]} does not precede node {i + 1}")
    if np.any((leaf_flag != 0) & (leaf_flag != 1)):
        raise DatasetError(source, "vocabulary isLeaf fields must be 0 or 1")
    if np.any((desc < 0) | (desc > 255)):
        i = int(np.flatnonzero(((desc < 0) | (desc > 255)).any(axis=1))[0])
        raise DatasetError(source, f"vocabulary line {i + 2}: descriptor byte outside 0..255")
    is_leaf = np.concatenate([[False], leaf_flag == 1])
    if np.any(is_leaf[parents[1:]]):
        raise DatasetError(source, "vocabulary has a node whose parent is a leaf")
    n_children = np.bincount(parents[1:], minlength=len(parents))
    childless = np.flatnonzero(~is_leaf & (n_children == 0))
    if len(childless):
        raise DatasetError(source, f"vocabulary inner node {childless[0]} has no children (crashes the native lookup)")
    if np.any(n_children > k):
        raise DatasetError(source, f"vocabulary node {int(np.argmax(n_children))} has more than k={k} children")
    w = np.concatenate([[0.0], weights])
    if not np.all(np.isfinite(w)):
        raise DatasetError(source, "vocabulary has a non-finite weight")
    if np.any(w[is_leaf] <= 0):
        raise DatasetError(source, f"vocabulary has {int(np.sum(w[is_leaf] <= 0))} leaf weights <= 0; "
                                   "ORB-SLAM3's BoW matching needs positive (IDF) weights")
    desc_all = np.concatenate([np.zeros((1, DESCRIPTOR_BYTES), np.int64), desc]).astype(np.uint8)
    return Vocabulary(k, L, parents, is_leaf, desc_all, w, scoring, weighting)


_CHUNK_LINES = 50_000  # parse big vocabularies (ORBvoc.txt: 1.1 M lines) in bounded memory


def _numeric_table(body: str, n_lines: int, source: str) -> np.ndarray:
    """(n_lines, 35) float64 of the node lines; DatasetError naming the first bad line."""
    n_fields = 2 + DESCRIPTOR_BYTES + 1
    out = np.empty((n_lines, n_fields), np.float64)
    lines = body.split("\n")
    for start in range(0, n_lines, _CHUNK_LINES):
        chunk = lines[start:start + _CHUNK_LINES]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                values = np.fromstring(" ".join(chunk), dtype=np.float64, sep=" ")
        except ValueError:  # numpy 2: unparsable text; the line loop below names it
            values = np.zeros(0)
        if values.size == len(chunk) * n_fields:
            out[start:start + len(chunk)] = values.reshape(len(chunk), n_fields)
            continue
        for j, line in enumerate(chunk):  # find and name the offending line
            fields = line.split()
            if len(fields) != n_fields:
                raise DatasetError(source, f"vocabulary line {start + j + 2}: expected {n_fields} fields "
                                           f"(parent isLeaf 32 bytes weight), got {len(fields)}")
            try:
                out[start + j] = [float(f) for f in fields]
            except ValueError:
                raise DatasetError(source, f"vocabulary line {start + j + 2}: non-numeric field "
                                           f"in {line[:40]!r}") from None
    return out


def read_vocabulary(path: str | Path) -> Vocabulary:
    """Read and validate a vocabulary file (plain text; the native loader reads no gzip)."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(p, "vocabulary file not found")
    try:
        text = read_regular(p, MAX_VOCABULARY_BYTES, "vocabulary").decode("ascii")
    except UnicodeDecodeError as err:
        raise DatasetError(p, f"vocabulary is not a readable text file ({err})") from err
    return parse_vocabulary(text, str(p))


def frame_descriptors(frames: Iterable[Frame], orb_cfg: OrbCfg) -> list[np.ndarray]:
    """One ORB descriptor array per frame (a frame = a document for the IDF weights)."""
    orb = make_orb(orb_cfg.n_features, orb_cfg.n_levels, orb_cfg.scale_factor, orb_cfg.fast_threshold)
    return [d for d in (detect(orb, f.rgb)[1] for f in frames) if len(d)]


@dataclass(frozen=True)
class BuildReport:
    """What ``slz vocab build`` reports."""

    path: str
    recordings: int
    frames: int
    descriptors: int
    nodes: int
    words: int
    size_bytes: int
    seconds: float


def build_from_recordings(paths: Sequence[str | Path], out: str | Path, config: Config,
                          force: bool = False) -> BuildReport:
    """Train a vocabulary from evenly spaced frames of the recordings, write it, and check it loads back.

    ``out`` may not be an input nor hold one, and an existing file there is replaced only with
    ``force`` and only when it is a vocabulary (``safe_output``); checked before the training and
    again before the write.
    """
    def check() -> None:
        safe_output.refuse_inputs(Path(out), [Path(p) for p in paths])
        safe_output.check_file(Path(out), force=force, ours=safe_output.is_vocabulary, label="a vocabulary")

    check()

    t0 = time.perf_counter()
    cfg = config.slam.vocab
    per_rec = max(1, cfg.max_frames // max(1, len(paths)))
    docs: list[np.ndarray] = []
    n_frames = 0
    for path in paths:
        with open_recording(path, config) as rec:
            total = max(1, rec.run_info().expected_frames)
            stride = max(1, total // per_rec)
            frames = (f for i, f in enumerate(rec.frames()) if i % stride == 0)
            got = frame_descriptors((f for _, f in zip(range(per_rec), frames, strict=False)), config.slam.orb)
        n_frames += len(got)
        docs += got
    n_desc = int(sum(len(d) for d in docs))
    if n_desc < cfg.k:
        raise DatasetError(str(paths[0]), f"only {n_desc} ORB descriptors found in {len(paths)} recording(s); "
                                          f"need at least slam.vocab.k={cfg.k} (textured frames)")
    vocab = train_vocabulary(docs, cfg.k, cfg.levels, cfg.iterations, cfg.seed)
    text = vocabulary_text(vocab)
    out = Path(out)
    parse_vocabulary(text, str(out))  # checked before it replaces anything
    check()
    write_text(out, text)
    return BuildReport(str(out), len(paths), n_frames, n_desc, vocab.n_nodes, vocab.n_words, len(text),
                       time.perf_counter() - t0)
