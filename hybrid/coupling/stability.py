"""The check after every step: each body's state finite and physically plausible."""
import math

import numba as nb
import numpy as np

from rigid.model import angular_velocity

# above these the run is declared unstable (no scene of everyday objects gets near them; a scene
# that starts beyond them is refused, see beyond_limits)
MAX_SPEED = 1.0e4       # m/s
MAX_DISTANCE = 1.0e6    # m


class InstabilityError(RuntimeError):
    """A body's state stopped being finite or physically plausible: ``body`` (its name), ``time``
    (s), ``quantity`` (what diverged, with its unit) and ``value``."""

    def __init__(self, body, time, quantity, value):
        self.body, self.time, self.quantity, self.value = body, time, quantity, value
        super().__init__(f"unstable: body '{body}' at t = {time:.6g} s: {quantity} = {value:.3g}")


class StepFailure(InstabilityError):
    """A step raised an unexpected exception: the run ends as unstable, like a divergence, naming
    the time (s), the ``stage`` (the innermost simulator function the error came from) and the
    ``error`` itself; ``body`` is None (the stage does not say which body)."""

    def __init__(self, time, stage, error):
        RuntimeError.__init__(self, f"unstable: a step failed at t = {time:.6g} s in {stage}: "
                                    f"{type(error).__name__}: {error}")
        self.body, self.time, self.quantity, self.value = None, time, stage, float("nan")
        self.stage, self.error = stage, error

    @classmethod
    def of(cls, time, error):
        """The failure of ``error`` raised by a step starting at ``time``, named by its stage."""
        stage, tb = "the step", error.__traceback__
        while tb is not None:
            code = tb.tb_frame.f_code
            module = tb.tb_frame.f_globals.get("__name__", "")
            if module.split(".")[0] in ("rigid", "fem", "hybrid"):
                stage = f"{module}.{code.co_name}"
            tb = tb.tb_next
        return cls(time, stage, error)


class OutputFailure(StepFailure):
    """Writing the run's output failed (a folder made unwritable, a full disk): not the physics,
    so the message says so, not 'unstable' (the run ends as for a StepFailure, status
    ``failed``)."""

    def __init__(self, time, error):
        RuntimeError.__init__(self, f"could not write the run's output at t = {time:.6g} s: "
                                    f"{type(error).__name__}: {error}")
        self.body, self.time, self.quantity, self.value = None, time, "output", float("nan")
        self.stage, self.error = "output", error


def check_finite(model, state):
    """Raise InstabilityError naming the first body whose state diverged."""
    rs = state.rigid
    if model.rigid.body_count:
        for quantity, values, limit in (("speed (m/s)", rs.velocity, MAX_SPEED),
                                        ("distance from origin (m)", rs.position, MAX_DISTANCE)):
            size = _row_norms(values)
            bad = ~np.isfinite(size) | (size > limit)
            if bad.any():
                i = int(np.argmax(bad))
                raise InstabilityError(model.names[model.rigid_ids[i]], state.time, quantity, float(size[i]))
        # the rim's speed, |w| times the body's radius, looked at exactly only where a bound on it
        # (|L| / the least moment) passes the limit (a box spun at 1e160 rad/s ran to "ok")
        rm = model.rigid
        bound = _row_norms(rs.angular_momentum) * rm.body_inv_inertia.max(axis=1) * rm.body_radius
        if not np.all(bound <= MAX_SPEED):
            rim = _row_norms(angular_velocity(rm, rs)) * rm.body_radius
            bad = ~np.isfinite(rim) | (rim > MAX_SPEED)
            if bad.any():
                i = int(np.argmax(bad))
                raise InstabilityError(model.names[model.rigid_ids[i]], state.time, "rim speed (m/s)",
                                       float(rim[i]))
    for j, s in enumerate(state.fem):
        speed, distance = largest_norms(s.v, s.x)
        for quantity, worst, limit in (("node speed (m/s)", speed, MAX_SPEED),
                                       ("node distance from origin (m)", distance, MAX_DISTANCE)):
            if not math.isfinite(worst) or worst > limit:
                k = int(model.fem_ids[j])
                if model.fragment_of is not None and model.fragment_of[k] != k and model.fem[j].node_load.any():
                    # (a 22 kN load on a piece broken off a brittle bar took it to 10 km/s)
                    quantity += (", a piece that broke off carrying a load: a load the body could not hold "
                                 "accelerates the piece without end")
                raise InstabilityError(model.names[k], state.time, quantity,
                                       worst if math.isfinite(worst) else float("nan"))


def beyond_limits(model, state):
    """``(body name, scene field, quantity, unit, value, limit)`` for each body whose state already
    passes a limit of :func:`check_finite` (a scene that starts there would stop as unstable at
    its first step): speed (``velocity``), rim speed (``angular_velocity``), distance from the
    origin (``position``); a deformable body's node speed is its ``velocity``'s, or its
    ``angular_velocity``'s when its centre moves within the limit."""
    rm, rs, found = model.rigid, state.rigid, []
    if rm.body_count:
        rim = _scaled_norms(angular_velocity(rm, rs)) * rm.body_radius
        for field, quantity, size, limit in (
                ("velocity", "speed", _scaled_norms(rs.velocity), MAX_SPEED),
                ("angular_velocity", "rim speed", rim, MAX_SPEED),
                ("position", "distance from the origin", _scaled_norms(rs.position), MAX_DISTANCE)):
            unit = "m" if field == "position" else "m/s"
            found += [(model.names[model.rigid_ids[i]], field, quantity, unit, float(size[i]), limit)
                      for i in np.nonzero(size > limit)[0]]
    for j, s in enumerate(state.fem):
        speed, distance = largest_norms(s.v, s.x)
        name = model.names[model.fem_ids[j]]
        if speed > MAX_SPEED:
            # the nodes' speed from the body's spin (its centre's speed within the limit)
            mass = model.fem[j].node_mass
            centre = _scaled_norms((mass @ s.v / mass.sum())[None])[0]
            field = "velocity" if not centre <= MAX_SPEED else "angular_velocity"
            found.append((name, field, "node speed", "m/s", speed, MAX_SPEED))
        if distance > MAX_DISTANCE:
            found.append((name, "position", "node distance from the origin", "m", distance, MAX_DISTANCE))
    return found


@nb.njit(cache=True)
def largest_norms(v, x):
    """The largest row norms of ``v`` and ``x`` (n, 3), in one pass; NaN for an array with a NaN
    anywhere."""
    worst_v = worst_x = 0.0
    nan_v = nan_x = False
    for i in range(len(v)):
        sv = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2]
        sx = x[i, 0] * x[i, 0] + x[i, 1] * x[i, 1] + x[i, 2] * x[i, 2]
        if sv != sv:
            nan_v = True
        elif sv > worst_v:
            worst_v = sv
        if sx != sx:
            nan_x = True
        elif sx > worst_x:
            worst_x = sx
    return (math.nan if nan_v else math.sqrt(worst_v)), (math.nan if nan_x else math.sqrt(worst_x))


def _scaled_norms(a):
    """Row norms (n,) of ``a`` (n, 3) that do not overflow for values past 1e154."""
    scale = np.abs(a).max(axis=1, initial=0.0)
    safe = np.where(scale > 0, scale, 1.0)[:, None]
    return scale * _row_norms(a / safe)


def _row_norms(a, squared=False):
    sq = np.einsum("ij,ij->i", a, a)
    return sq if squared else np.sqrt(sq)
