"""Shock propagation (Guendelman, Bridson, Fedkiw 2003): the level of each body in a stack's
contact graph, and per contact the inverse-mass scales that freeze its lower side, so a stack can
be swept bottom-up (rigid.resolve)."""
import numba as nb
import numpy as np

from .solver import solve_groups

# a contact stacks one body on another when its normal is within ~70 degrees of up
STACK_COS = 0.34


@nb.njit(cache=True)
def stack_levels(ia, ib, normal, up, body_count, is_static, group_of, carries):
    """Height of each body in the contact graph (Guendelman 2003 shock propagation).

    Static bodies are level 0; a body resting (normal within ~70 degrees of up) on a body of level
    k through a contact that ``carries`` (c,) bool (a load: a speculative contact across a gap
    does not) has level <= k + 1. (Counted, the ground 1 mm under the middle cube of a stack of
    1 mm cubes, within the 5 mm contact margin, put every cube at the level of the lowest: the
    stack was not swept level by level, and it leaned 5 degrees in 0.5 s.) The particles of one
    group (``group_of`` >= 0, the touched nodes of one deformable body) are one body: all take
    the level of the lowest (a slab lying on the ground carries what rests on its top). Bodies
    touching nothing below them get a level above every other.
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
            if not carries[k]:
                continue
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


@nb.njit(cache=True)
def shock_scales(body_a, body_b, level):
    """Per contact: which level it belongs to (the higher of its two sides' levels, the static
    world at 0) and the inverse-mass scales that freeze its lower side (0 on the lower side, 1
    on the other; both 1 at equal levels)."""
    c = len(body_a)
    contact_level = np.empty(c, dtype=np.int64)
    scale_a = np.empty(c)
    scale_b = np.empty(c)
    for k in range(c):
        la = level[body_a[k]] if body_a[k] >= 0 else 0
        lb = level[body_b[k]] if body_b[k] >= 0 else 0
        contact_level[k] = max(la, lb)
        scale_a[k] = 0.0 if la < lb else 1.0
        scale_b[k] = 0.0 if lb < la else 1.0
    return contact_level, scale_a, scale_b


@nb.njit(cache=True)
def sweep_levels(ia, ib, ra, rb, point, normal, up, static, selected, target, friction, lam,
                 inv_m, invI, v, w, iterations, group_of, groups, impulse, apply_lam):
    """Shock propagation (Guendelman 2003): the contacts ``selected`` (world points ``point``)
    solved again (rigid.solver.pgs_at, ``iterations`` sweeps) level by level up the stack (``up``,
    unit), lowest first, each level with the lower side of its contacts frozen; their impulses
    replace theirs in ``impulse`` (c, 3); v, w and lam are updated in place. ``group_of``: each
    solver body's group (-1: not a particle); ``groups``: rigid.solver.solver_groups of the
    contacts; ``apply_lam`` (False: the velocities include lam; an argument, not a literal, so
    that the sweeps compiled for the contact pass serve here too). Returns the per-contact
    inverse-mass scales (scale_a, scale_b) that freeze the lower sides."""
    level = stack_levels(ia, ib, normal, up, len(inv_m), static, group_of, lam[:, 0] > 0.0)
    contact_level, scale_a, scale_b = shock_scales(ia, ib, level)
    top = -1
    for k in range(len(ia)):
        if selected[k]:
            top = max(top, contact_level[k])
    at_level = np.empty(len(ia), dtype=np.bool_)
    for lv in range(top + 1):
        count = 0
        for k in range(len(ia)):
            at_level[k] = selected[k] and contact_level[k] == lv
            count += at_level[k]
        if count == 0:
            continue
        level_impulse = solve_groups(ia, ib, ra, rb, point, normal, target, friction, scale_a,
                                     scale_b, at_level, lam, inv_m, invI, v, w, iterations, groups,
                                     apply_lam)
        for k in range(len(ia)):
            if at_level[k]:
                for d in range(3):
                    impulse[k, d] = level_impulse[k, d]
    return scale_a, scale_b
