"""The run's progress bar: one line on stderr, on a terminal redrawn in place, else a line per
tenth of the run (and at least one a minute)."""
import math
import sys
import time as clock


class Progress:
    """A one-line progress bar on stderr (simulated time, steps/s and the wall time left at the
    rate of the last RECENT to 2 RECENT seconds); quiet when disabled."""

    RECENT = 5.0    # s of wall time
    QUIET_AT_MOST = 60.0    # s of wall time between lines off a terminal (a 10k-tet impact's slow steps)

    def __init__(self, duration, enabled=True, stream=sys.stderr, first_steps=0):
        self.duration, self.enabled, self.stream = duration, enabled, stream
        self.first_steps = first_steps          # steps taken before this bar: not in its rate
        self.start = clock.perf_counter()
        self.last = -1.0
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.last_decile, self.last_shown, self.last_line = -1, None, self.start
        # simulated time to a thousandth of the duration (a 20 ms run read t = 0.000 s for a while)
        # (past nine places, in powers of ten: a run of 1e-10 s read t = 0.000000000 s throughout)
        places = math.ceil(3 - math.log10(duration)) if duration > 0 else 3
        self.places = f".{max(3, places)}f" if places <= 9 else ".3e"
        # (wall s, steps, simulated s) where the rate is taken from, and the next such mark: a
        # pile that slows as it lands read 3x its later rate when the rate was the whole run's
        self.since = self.mark = None

    def update(self, t, steps, force=False):
        """Show simulated time ``t`` (s) after ``steps`` steps; on a terminal at most every 0.2 s
        of wall time, else once per tenth of the duration, unless ``force``."""
        if not self.enabled:
            return
        now = clock.perf_counter()
        if self.since is None:
            self.since = self.mark = (self.start, self.first_steps, t)
        if now - self.mark[0] >= self.RECENT:
            self.since, self.mark = self.mark, (now, steps, t)
        frac = min(t / self.duration, 1.0) if self.duration > 0 else 1.0
        wall, steps0, t0 = self.since
        rate = (steps - steps0) / max(now - wall, 1e-9)
        left = ""
        if t > t0 and frac < 1.0:
            seconds = int((self.duration - t) * (now - wall) / (t - t0))
            if seconds >= 1:
                hours = f"{seconds // 3600}:" if seconds >= 3600 else ""
                left = f"  {hours}{seconds // 60 % 60:02d}:{seconds % 60:02d} left"
        if self.tty:
            if force or now - self.last > 0.2:
                bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
                self.stream.write(f"\r[{bar}] t = {t:7{self.places}} / {self.duration:{self.places}} s  "
                                  f"{_rate(rate):>8} steps/s{left}\033[K")
                self.stream.flush()
                self.last = now
        elif int(frac * 10) > self.last_decile or (force and steps != self.last_shown) \
                or (now - self.last_line >= self.QUIET_AT_MOST and steps != self.last_shown):
            self.last_decile, self.last_shown, self.last_line = int(frac * 10), steps, now
            self.stream.write(f"{100 * frac:5.1f}%  t = {t:{self.places}} s  {_rate(rate)} steps/s{left}\n")
            self.stream.flush()

    def done(self):
        """End the bar's line (on a terminal)."""
        if self.enabled and self.tty:
            self.stream.write("\n")


def _rate(rate):
    """Steps per second to three figures, whole from 100 on (1780, not 1.78e+03; 0.111, not 0.0)."""
    return f"{rate:.0f}" if rate >= 100 else f"{rate:.3g}"
