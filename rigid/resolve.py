"""Contact resolution of one step: collisions, resting contact, shock propagation and
penetration recovery, over generic solver bodies.

Impacts found inside a step get their restitution at their time of impact: the impulse comes from
the approach velocity at that instant and the body is moved back by ``tau * dv`` (as if the velocity
had changed at ``t + tau`` rather than at ``t``), so bounce heights do not depend on where in a step
an impact falls. :func:`resolve_contacts` works on generic solver bodies (:class:`SolverBodies`),
so the coupled stepper passes FEM surface nodes through the same passes as particles.
"""
from dataclasses import dataclass

import numpy as np

from .collide import collide, finite
from .patches import share_loads, spinning_patches
from .shock import sweep_levels
from .solver import arms, contact_basis, normal_velocity, solve_groups, solver_groups
from .step_kernels import contact_targets, impact_kinematics


@dataclass
class ContactSettings:
    """Solver parameters (scene fields under [simulation.solver] set some of them).

    iterations: Gauss-Seidel sweeps per pass. deformable_iterations: sweeps of the contact pass
    when any contact is on a deformable body. margin m: contacts are kept while the gap is below
    it (plus the distance the bodies can travel in the step). slop m: penetration tolerated without
    correction. recovery: fraction of the penetration beyond ``slop`` removed per step (positions
    only, no velocity is added). restitution_threshold m/s: slower impacts are resting contact (no
    bounce, no jitter). shock_iterations: sweeps per level of shock propagation. max_substeps: cap
    on adaptive substeps, taken when a body would move more than half the thinnest body's
    thickness in one step. hold_resting: deformable bodies resting on static ground are stepped
    with their resting nodes held (hybrid.coupling.resting).
    """
    iterations: int = 20
    deformable_iterations: int = 100
    margin: float = 0.005
    slop: float = 0.0005
    recovery: float = 0.4
    restitution_threshold: float = 0.05
    shock_iterations: int = 10
    max_substeps: int = 32
    hold_resting: bool = True


@dataclass
class SolverBodies:
    """Bodies as the contact solver sees them (n = rigid bodies + particles), world frame.

    inv_mass (n,) 1/kg; inv_inertia (n, 3, 3) 1/(kg m^2), zero for particles and fixed bodies;
    position (n, 3) m; velocity (n, 3) m/s, the velocity the step drifts with; velocity_at_t
    (n, 3) m/s, the velocity at the start of the step (for times of impact); angular (n, 3) rad/s;
    accel (n, 3) m/s^2, free acceleration during the step (gravity); static (n,) bool.
    Particles (FEM surface nodes in contact) have group_of >= 0: the particles of group g (one
    deformable body) answer impulses through the group's Delassus matrix, block-sparse by rows
    (w_ptr (n + 1,), w_col, W (nnz, 3, 3)), in the group's frame, whose rotation to world is
    group_R[g] (see rigid.solver.pgs). Places (points of a deformable surface between its
    nodes) are particles without block rows whose velocity and impulses are shared among three
    particles: corner (n, 3) solver indices (-1 in column 0 for every other body) with weights
    corner_w (n, 3). No particles: group_of all -1.
    """
    inv_mass: np.ndarray
    inv_inertia: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    velocity_at_t: np.ndarray
    angular: np.ndarray
    accel: np.ndarray
    static: np.ndarray
    group_of: np.ndarray = None
    group_R: np.ndarray = None
    w_ptr: np.ndarray = None
    w_col: np.ndarray = None
    W: np.ndarray = None
    corner: np.ndarray = None
    corner_w: np.ndarray = None

    def groups(self):
        """(group_of, group_R, w_ptr, w_col, W, corner, corner_w) for the solver kernel (empty
        when there are no particles or places)."""
        n = len(self.inv_mass)
        corner = np.full((n, 3), -1, np.int64) if self.corner is None else self.corner
        corner_w = np.zeros((n, 3)) if self.corner_w is None else self.corner_w
        if self.group_of is None:
            return (np.full(n, -1, np.int64), np.eye(3)[None], np.zeros(n + 1, np.int64),
                    np.zeros(1, np.int64), np.zeros((1, 3, 3)), corner, corner_w)
        return self.group_of, self.group_R, self.w_ptr, self.w_col, self.W, corner, corner_w


@dataclass
class Resolution:
    """What contact resolution did (all (n, 3)): new velocity and angular velocity (m/s, rad/s),
    position and rotation shifts for impulses that acted at their time of impact (m, rad),
    pseudo-velocities that remove penetration (positions only), the part of the velocity change
    due to impacts (m/s), angular momentum corrections (kg m^2/s) that keep L exact; per contact
    (c, 3): the collision impulse and the contact-pass impulse on side a (world, N s), and the
    contact pass's accumulated impulses in its contact basis (to warm-start a repeat solve), and
    the penetration recovery's pseudo-impulses on side a (world, N s times s: a deformable body
    moves its positions by its response to them) with the share ``(c, 2)`` each side took (0 on a
    side shock propagation froze, else 1); per body (n,) bool, ``bouncing``: in a group of
    bodies touching through an impact with restitution (None: no impact)."""
    velocity: np.ndarray
    angular: np.ndarray
    shift: np.ndarray
    shift_rotation: np.ndarray
    pseudo_velocity: np.ndarray
    pseudo_angular: np.ndarray
    impact_dv: np.ndarray
    momentum_fix: np.ndarray
    collision_impulse: np.ndarray = None
    contact_impulse: np.ndarray = None
    contact_lambda: np.ndarray = None
    pseudo_impulse: np.ndarray = None
    pseudo_share: np.ndarray = None
    impact: np.ndarray = None
    bouncing: np.ndarray = None


@dataclass
class _Problem:
    """One call's contacts as the solver kernel takes them: the contacts, their arms ra, rb
    (c, 3) m on sides a and b, the solver bodies, each solver body's group (-1: not a particle)
    and what the compiled sweeps take for the particles (rigid.solver.solver_groups: None when
    there are none), made once for every pass over these contacts."""
    contacts: object
    ra: np.ndarray
    rb: np.ndarray
    bodies: SolverBodies
    group_of: np.ndarray
    groups: tuple | None

    @classmethod
    def of(cls, contacts, bodies):
        groups = bodies.groups()
        return cls(contacts, *arms(contacts.body_a, contacts.body_b, contacts.point, bodies.position),
                   bodies, groups[0], solver_groups(contacts.body_a, contacts.body_b, groups))

    def solve(self, target, friction, scale_a, scale_b, active, lam, v, w, iterations,
              apply_lam=False):
        """:func:`rigid.solver.pgs_at` over these contacts (updates v, w and lam in place)."""
        c, b = self.contacts, self.bodies
        return solve_groups(c.body_a, c.body_b, self.ra, self.rb, c.point, c.normal, target,
                            friction, scale_a, scale_b, active, lam, b.inv_mass, b.inv_inertia, v, w,
                            iterations, self.groups, apply_lam)

    def sweep_stack(self, up, selected, target, lam, v, w, iterations, impulse):
        """Shock propagation (Guendelman 2003): the contacts ``selected`` solved again level by
        level up the stack (``up``, unit), each level with the lower side of its contacts frozen;
        their impulses replace theirs in ``impulse``. Returns the per-contact inverse-mass scales
        (scale_a, scale_b) that freeze the lower sides."""
        c, b = self.contacts, self.bodies
        return sweep_levels(c.body_a, c.body_b, self.ra, self.rb, c.point, c.normal, up, b.static,
                            selected, target, c.friction, lam, b.inv_mass, b.inv_inertia, v, w,
                            iterations, self.group_of, self.groups, impulse, False)


def resolve_contacts(bodies, contacts, h, gravity, settings, previous=None, warm=None):
    """Collisions, resting contact, shock propagation and penetration recovery for one step.

    ``previous``: the Resolution of an earlier solve of the same step; this one starts from its
    accumulated contact impulses (which it may lower as well as raise) and its position shifts,
    and does no new collisions or penetration recovery (coupling rounds).
    ``warm``: (c, 3) world impulses on side a to start the contact pass from (a guess, e.g. last
    step's impulses of persisting contacts; the sweeps lower or raise them as needed). Ignored
    with ``previous``.
    """
    n, c = len(bodies.inv_mass), contacts.count
    v, w = bodies.velocity.copy(), bodies.angular.copy()
    out = Resolution(v, w, *(np.zeros((n, 3)) for _ in range(6)), *(np.zeros((c, 3)) for _ in range(3)))
    if c == 0:
        return out
    problem = _Problem.of(contacts, bodies)
    # contacts on deformable bodies (particles) bounce through the body's own elasticity
    particle = problem.group_of >= 0
    ia, ib = contacts.body_a, contacts.body_b
    on_particle = particle[ia] | (particle[np.maximum(ib, 0)] & (ib >= 0))

    # 1. collisions: restitution at each impact's time within the step
    if previous is not None:     # position-level results belong to the first solve of the step
        for name in ("shift", "shift_rotation", "pseudo_velocity", "pseudo_angular", "impact_dv",
                     "momentum_fix", "collision_impulse", "pseudo_impulse", "pseudo_share", "impact",
                     "bouncing"):
            setattr(out, name, getattr(previous, name))
    else:
        impact, tau, approach = _impacts(problem, on_particle, h, gravity, settings)
        out.impact = impact
        if impact.any():
            # (inelastic impacts end in the contact pass the same way with or without the supports)
            bouncing = bool((contacts.restitution[impact] > 0).any())
            collide(out, problem, impact, ~impact & ~on_particle & bouncing, tau, approach, h,
                    gravity, settings)

    # 2. contact: no gap may close by the end of the step (inelastic, Coulomb friction)
    target = _contact_target(problem, out, h, settings.slop)
    lam, apply_lam = _contact_start(contacts, previous, warm)
    # contacts on deformable bodies converge more slowly (a 1,800 kg box on a 1.8 kg slab sank
    # into it at 10 um/s after 20 sweeps): with any of them, the sweeps go on longer
    sweeps = max(settings.iterations, settings.deformable_iterations) if on_particle.any() \
        else settings.iterations
    # a few contacts sweep on while they have not converged, within a budget of contact visits: at
    # 20 sweeps a pyramid of four spheres crept 11 mm in 10 s, its speed rising (at 40: 0.005 mm);
    # a pile of 100 boxes (1,000 contacts) or a stack of twelve (100) keeps its 20
    sweeps = max(sweeps, min(SMALL_SWEEPS, SWEEP_BUDGET // max(c, 1)))
    ones = np.ones(c)
    contact_imp = problem.solve(target, contacts.friction, ones, ones, np.ones(c, dtype=bool), lam,
                                v, w, sweeps, apply_lam)
    _share_spinning_patches(problem, ~on_particle, target, lam, v, w, settings.iterations, contact_imp)

    # 3. shock propagation: sweep stacks bottom-up with the lower side frozen (Guendelman 2003)
    scale_a = scale_b = ones
    gnorm = np.linalg.norm(gravity)
    if gnorm > 0:
        up = -np.asarray(gravity) / gnorm
        scale_a, scale_b = problem.sweep_stack(up, _stacked(particle, ia, ib, contacts.normal @ up),
                                               target, lam, v, w, settings.shock_iterations,
                                               contact_imp)
    out.contact_impulse = finite(contact_imp)
    out.contact_lambda = lam

    # 4. penetration recovery: move positions only (split impulse), never add velocity
    deep = contacts.gap < -settings.slop
    if deep.any() and previous is None:
        target_p = settings.recovery * (-contacts.gap - settings.slop) / h
        out.pseudo_impulse = finite(problem.solve(
            target_p, np.zeros(c), scale_a, scale_b, deep, np.zeros((c, 3)), out.pseudo_velocity,
            out.pseudo_angular, settings.iterations))
        out.pseudo_share = np.stack([scale_a, scale_b], axis=1)
    return out


def _impacts(problem, on_particle, h, gravity, settings):
    """Which contacts are impacts this step, with their time of impact tau (s) and approach speed
    (m/s) at that time, all (c,). An impact closes its gap within the step faster than the
    restitution threshold; contacts on deformable bodies (``on_particle``) are never impacts, and
    a rigid body's impacts after its first hit on a deformable body this step wait for the
    contact pass."""
    contacts, bodies = problem.contacts, problem.bodies
    ia, ib = contacts.body_a, contacts.body_b
    ib0 = np.maximum(ib, 0)
    # (time_of_impact of the relative normal velocity and acceleration, compiled)
    tau, approach = impact_kinematics(ia, ib, problem.ra, problem.rb, contacts.normal,
                                      contacts.gap, bodies.velocity_at_t, bodies.angular,
                                      bodies.accel, float(h))
    # slower approaches are resting contact, left to the contact pass (no bounce, no jitter)
    threshold = max(settings.restitution_threshold, 2.0 * np.linalg.norm(gravity) * h)
    hits = (tau <= h) & (approach > threshold)
    impact, soft = hits & ~on_particle, hits & on_particle
    if soft.any():
        # a rigid body that strikes a deformable body first this step is stopped by it in the
        # contact pass; its later impacts wait there too (a ball at 40 m/s above a plate lying on
        # the ground struck the ground through the plate, and bounced off both)
        first = np.full(len(bodies.inv_mass), np.inf)
        np.minimum.at(first, ia[soft], tau[soft])
        np.minimum.at(first, ib0[soft & (ib >= 0)], tau[soft & (ib >= 0)])
        impact &= (tau < first[ia]) & ((ib < 0) | (tau < first[ib0]))
    return impact, tau, approach


def _stacked(particle, ia, ib, up_normal):
    """The contacts shock propagation sweeps (c,) bool: between rigid bodies or with the static
    world, and of a deformable body's particle resting on a rigid body (above it: the normal,
    towards side a, along ``up_normal`` = normal . up). A particle against the static world gains
    nothing from it, and one under a rigid body is left to the contact pass. A 975 kg steel block
    landing on a 1 kg box on the ground, its contacts with the box left to the contact pass, rose
    above its release height (+847 J): 100 sweeps converge slowly at 1000:1."""
    b_particle = (ib >= 0) & particle[np.maximum(ib, 0)]
    b_rigid = (ib >= 0) & ~b_particle
    rigid_pair = ~particle[ia] & ~b_particle
    on_rigid = (particle[ia] & b_rigid & (up_normal > 0)) | (~particle[ia] & b_particle & (up_normal < 0))
    return rigid_pair | on_rigid


def _contact_target(problem, out, h, slop):
    """Normal velocity (c,) m/s each contact may reach at most: closing its gap exactly by the end
    of the step, counting the shifts the collision pass gave the bodies, but no more separating
    than it already is (by more than ``slop`` (m) in the step, for contacts that were no impact)."""
    c = problem.contacts
    target = contact_targets(c.body_a, c.body_b, problem.ra, problem.rb, c.normal, c.gap,
                             out.shift, out.shift_rotation, float(h))
    # a shift that leaves a contact deeper than its gap (impacts at different times in the step,
    # moved back together) is not pushed out faster than the contact already separates, a
    # support by at most the slop in the step: that adds velocity (a box landing on a corner at
    # 4.75 m/s left at 6.65, its energy doubled); penetration recovery moves it out
    vn = normal_velocity(c.body_a, c.body_b, problem.ra, problem.rb, c.normal, out.velocity, out.angular)
    allowed = slop / h if out.impact is None else np.where(out.impact, 0.0, slop / h)
    return np.minimum(target, np.maximum(vn, 0.0) + allowed)


# the sweeps of a contact pass with few contacts: up to SMALL_SWEEPS, within SWEEP_BUDGET contact
# visits (they stop once converged, rigid.solver._sweeps)
SMALL_SWEEPS = 100
SWEEP_BUDGET = 2000

# rounds of sharing and sweeping at most, done once no normal impulse moves by SHARE_TOL of the largest
SHARE_ROUNDS = 4
SHARE_TOL = 1e-3


def _share_spinning_patches(problem, rigid_pair, target, lam, v, w, iterations, impulse):
    """Flat patches that turn about their normal (rigid.patches): their normal impulses shared
    out over the patch (same total force and moment: the velocities stay), then their contacts
    swept again so friction acts at every point's arm; their impulses replace theirs in
    ``impulse`` (c, 3)."""
    contacts = problem.contacts
    patches = spinning_patches(contacts.body_a, contacts.body_b, contacts.point, contacts.normal,
                               rigid_pair, w)
    if patches is None:
        return
    rows, starts = patches
    active = np.zeros(contacts.count, dtype=bool)
    active[rows] = True
    ones = np.ones(contacts.count)
    for _ in range(SHARE_ROUNDS):
        load = np.ascontiguousarray(lam[:, 0])
        share_loads(contacts.point, contacts.normal, rows, starts, load)
        lam[:, 0] = load
        again = problem.solve(target, contacts.friction, ones, ones, active, lam, v, w, iterations)
        # done once the sweeps keep the shared split (a patch that friction holds still)
        if np.abs(lam[rows, 0] - load[rows]).max() <= SHARE_TOL * load[rows].max():
            break
    impulse[active] = again[active]


def _contact_start(contacts, previous, warm):
    """Accumulated impulses (c, 3) the contact pass starts from, and whether they still have to
    be applied to the bodies (a warm start) or already are (a repeat solve of the step)."""
    if previous is not None:
        return previous.contact_lambda.copy(), False
    if warm is not None:
        return warm_lambda(contacts.normal, contacts.friction, warm), True
    return np.zeros((contacts.count, 3)), False


def warm_lambda(normal, friction, impulse):
    """World impulses (c, 3) as accumulated impulses in each contact's basis (normal, t1, t2), made
    admissible: normal part >= 0, friction inside the Coulomb disk."""
    lam = np.einsum("cdk,ck->cd", contact_basis(normal), impulse)
    lam[:, 0] = np.maximum(lam[:, 0], 0.0)
    tangential = np.linalg.norm(lam[:, 1:], axis=1)
    limit = friction * lam[:, 0]
    over = tangential > limit
    lam[over, 1:] *= (limit[over] / tangential[over])[:, None]
    return lam
