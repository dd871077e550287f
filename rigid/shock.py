"""Shock propagation (Guendelman, Bridson, Fedkiw 2003): the level of each body in a stack's
contact graph, and per contact the inverse-mass scales that freeze its lower side, so a stack can
be swept bottom-up (rigid.resolve)."""
import numba as nb
import numpy as np

# a contact stacks one body on another when its normal is within ~70 degrees of up
STACK_COS = 0.34


@nb.njit(cache=True)
def stack_levels(ia, ib, normal, up, body_count, is_static, group_of):
    """Height of each body in the contact graph (Guendelman 2003 shock propagation).

    Static bodies are level 0; a body resting (normal within ~70 degrees of up) on a body of level
    k has level <= k + 1. The particles of one group (``group_of`` >= 0, the touched nodes of one
    deformable body) are one body: all take the level of the lowest (a slab lying on the ground
    carries what rests on its top). Bodies touching nothing below them get a level above every other.
    """
    big = body_count + 1
    level = np.full(body_count, big, dtype=np.int64)
    for i in range(body_count):
        if is_static[i]:
            level[i] = 0
    groups = 0
    for i in range(body_count):
        groups = max(groups, group_of[i] + 1)
    lowest = np.empty(groups, dtype=np.int64)
    changed = True
    sweeps = 0
    while changed and sweeps < 2 * body_count + 2:
        changed = False
        sweeps += 1
        lowest[:] = big
        for i in range(body_count):
            if group_of[i] >= 0:
                lowest[group_of[i]] = min(lowest[group_of[i]], level[i])
        for i in range(body_count):
            if group_of[i] >= 0 and lowest[group_of[i]] < level[i]:
                level[i] = lowest[group_of[i]]
                changed = True
        for k in range(len(ia)):
            s = normal[k, 0] * up[0] + normal[k, 1] * up[1] + normal[k, 2] * up[2]
            if s > STACK_COS:
                upper, lower = ia[k], ib[k]
            elif s < -STACK_COS:
                upper, lower = ib[k], ia[k]
            else:
                continue
            lower_level = 0 if lower < 0 else level[lower]
            if upper >= 0 and lower_level + 1 < level[upper]:
                level[upper] = lower_level + 1
                changed = True
    top = 0
    for i in range(body_count):
        if level[i] < big and level[i] > top:
            top = level[i]
    for i in range(body_count):
        if level[i] == big:
            level[i] = top + 1
    return level


def shock_scales(body_a, body_b, level):
    """Per contact: which level it belongs to and the inverse-mass scales that freeze its lower side."""
    la = np.where(body_a >= 0, level[np.maximum(body_a, 0)], 0)
    lb = np.where(body_b >= 0, level[np.maximum(body_b, 0)], 0)
    contact_level = np.maximum(la, lb)
    scale_a = np.where(la < lb, 0.0, 1.0)
    scale_b = np.where(lb < la, 0.0, 1.0)
    return contact_level, scale_a, scale_b
