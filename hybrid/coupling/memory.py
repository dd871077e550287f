"""Contact identity across steps, and the impulses remembered under it (the solver's warm start).

Keys number node contacts so that the same contact in the next step gets the same key: a stacked
surface node against a rigid body, a plane or another body's surface node, and a rigid sample
point against a surface node.
"""
from dataclasses import dataclass

import numpy as np


def contact_keys(a, b, node_count, rigid_count, node_pairs):
    """Identity of node contacts across steps (int64): stacked surface node ``a`` against stacked
    node ``b`` (``node_pairs``), or against rigid body ``b`` (-1: a plane). Ordered pairs of
    distinct (a, b) give distinct keys."""
    other = b if node_pairs else node_count + 1 + b
    return (np.asarray(a, np.int64) * (node_count + rigid_count + 1) + other).astype(np.int64)


def point_keys(point, node, node_count, rigid_count):
    """Identity across steps of rigid sample point ``point`` against stacked surface node ``node``
    (int64), above every key of :func:`contact_keys`."""
    base = (node_count + 1) * (node_count + rigid_count + 1) + 1
    return (base + np.asarray(point, np.int64) * (node_count + 1) + np.asarray(node, np.int64)).astype(np.int64)


@dataclass(frozen=True)
class ContactMemory:
    """Last step's contact-pass impulses of node contacts (world, on side a, N s) by contact key:
    resting contact persists, so they start the next contact pass close to its answer (warm
    start); only a starting guess, the solver raises or lowers them as the new step needs.

    keys (c,) int64, sorted; impulse (c, 3) N s.
    """
    keys: np.ndarray
    impulse: np.ndarray

    @staticmethod
    def of(keys, impulse):
        """The memory of contacts ``keys`` (c,) int64 with impulses ``impulse`` (c, 3) N s; rows
        with no key (negative) or a non-finite impulse are dropped, the rest sorted by key."""
        keep = (keys >= 0) & np.isfinite(impulse).all(axis=1)
        order = np.argsort(keys[keep], kind="stable")
        return ContactMemory(keys[keep][order], impulse[keep][order])

    def recall(self, keys):
        """(c, 3) remembered impulses for ``keys`` (zero where a contact is new or not a node's)."""
        out = np.zeros((len(keys), 3))
        if len(self.keys) == 0:
            return out
        at = np.clip(np.searchsorted(self.keys, keys), 0, len(self.keys) - 1)
        hit = (self.keys[at] == keys) & (keys >= 0)
        out[hit] = self.impulse[at[hit]]
        return out
