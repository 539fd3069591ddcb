"""A tf tree that stays a tree: each frame has one parent and no chain comes back to where it started.

tf (REP 105) composes a frame's pose by walking child -> parent links to the root. A frame given a
second parent (two broadcasters of one child, or a ``/tf_static`` and a ``/tf`` edge that disagree)
makes the walk depend on which message came last: a camera placed 100 m off by another tree's link
looks as plausible as the right one. So a second parent, a frame that is its own parent, or an
edge that closes a cycle is refused with the frames named (``TfTreeError``); re-sending the same
edge with a new transform (a moving frame) is how tf works and is accepted.

Pure functions over the tree dict every reader keeps (child -> (parent, T_parent_child)), with
leading '/' already stripped (``decode.decode_tf``). Callers turn ``TfTreeError`` into their own
error with the file and topic.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, MutableMapping

import numpy as np

from slzcli.errors import SlzError

Tree = MutableMapping[str, tuple[str, np.ndarray]]


class TfTreeError(SlzError):
    """An edge that would make a tf tree no longer a tree; the message names the frames."""


def parent_of(tree: Mapping[str, tuple[str, np.ndarray]], child: str) -> str | None:
    """The parent frame of ``child`` (None: a root, or not in the tree)."""
    edge = tree.get(child)
    return None if edge is None else edge[0]


def edge_problem(tree: Mapping[str, tuple[str, np.ndarray]], parent: str, child: str) -> str | None:
    """Why ``parent -> child`` cannot join ``tree`` (None: it can: new, or the same edge again)."""
    if not child:
        return f"a transform from {parent!r} names no child frame"
    if parent == child:
        return f"frame {child!r} is given itself as parent"
    old = parent_of(tree, child)
    if old is not None and old != parent:
        return f"frame {child!r} has two parents, {old!r} and {parent!r} (a tf tree gives each frame one parent)"
    if old is None:
        node: str | None = parent
        seen = [child, parent]
        while node is not None:
            node = parent_of(tree, node)
            if node == child:
                links = " -> ".join([*seen, child])
                return f"the transform {parent!r} -> {child!r} closes a cycle of child -> parent links {links}"
            if node is not None:
                if node in seen:  # a cycle already above (refused when it was added): stop walking
                    break
                seen.append(node)
    return None


def add_edge(tree: Tree, parent: str, child: str, T_parent_child: np.ndarray) -> None:
    """Put one transform into ``tree``; TfTreeError when it would make it no longer a tree."""
    problem = edge_problem(tree, parent, child)
    if problem is not None:
        raise TfTreeError(problem)
    tree[child] = (parent, T_parent_child)


def add_edges(tree: Tree, transforms: Iterable[tuple[int, str, str, np.ndarray]]) -> None:
    """Every (stamp, parent, child, T) of a TFMessage (``decode.decode_tf``) into ``tree``."""
    for _, parent, child, T in transforms:
        add_edge(tree, parent, child, T)


def merge_problem(static: Mapping[str, tuple[str, np.ndarray]],
                  dynamic: Mapping[str, tuple[str, np.ndarray]]) -> str | None:
    """Why the ``/tf_static`` and ``/tf`` trees do not make one tree together (None: they do)."""
    joined: dict[str, tuple[str, np.ndarray]] = dict(static)
    for child, (parent, T) in dynamic.items():
        problem = edge_problem(joined, parent, child)
        if problem is not None:
            return problem
        joined[child] = (parent, T)
    return None
