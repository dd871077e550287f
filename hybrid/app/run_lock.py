"""One run at a time in a run folder.

Two runs writing into one folder (two terminals given the same ``--out``, two scripts, two
threads) would remove each other's frames and interleave their tables. A run takes the folder's
lock file (``.hybrid-run.lock``: the process id and host of the run) as it starts writing there and
removes it when its files are closed. A lock whose process has ended (a run killed with SIGKILL, a
machine that went down) is taken over; one held by a live process, or by a process on another host
(which cannot be asked), refuses the run with :class:`RunFolderBusy`.
"""
import os
import socket
import threading
from pathlib import Path

LOCK_FILE = ".hybrid-run.lock"

_held = set()                  # the run folders (resolved) a run of this process writes now
_guard = threading.Lock()


class RunFolderBusy(ValueError):
    """Another run is writing in the run folder (its message says which and what to do)."""


def holder(folder):
    """Why ``folder`` cannot take a run now (a sentence naming the run writing there), or None
    when no live run holds its lock."""
    path = Path(folder) / LOCK_FILE
    try:
        text = path.read_text(errors="replace").split()
    except OSError:
        return None
    pid = int(text[0]) if text and text[0].isdigit() else None
    host = text[1] if len(text) > 1 else None
    if pid is None:                                        # a damaged lock: nobody can hold it
        return None
    if host != socket.gethostname():
        return (f"a run on host {host} (process {pid}) holds {path}; if no run writes there any more "
                f"(it was killed), delete that file")
    if pid == os.getpid():
        return "another run of this process writes there" if _key(folder) in _held else None
    if _alive(pid) and not _started_after(pid, path):
        return (f"another run (process {pid}) writes there; give another folder or wait for it "
                f"(if no run writes there, delete {path})")
    return None


def check(folder):
    """RunFolderBusy naming the live run that holds ``folder``'s lock, if one does."""
    why = holder(folder)
    if why is not None:
        raise RunFolderBusy(f"out {folder}: {why}")


def acquire(folder):
    """Take ``folder``'s lock for a run of this process (the folder exists); RunFolderBusy when a
    live run holds it."""
    key = _key(folder)
    with _guard:
        check(folder)
        path = Path(folder) / LOCK_FILE
        temporary = path.with_name(f"{LOCK_FILE}.{os.getpid()}.{threading.get_ident()}")
        try:
            temporary.write_text(f"{os.getpid()} {socket.gethostname()}\n")
        except OSError:                        # (a full disk: no stray temporary left)
            temporary.unlink(missing_ok=True)
            raise
        try:
            os.link(temporary, path)           # (atomic: fails if another run took it meanwhile)
        except FileExistsError:
            # a stale lock (its process ended), or one just taken by another run: look again
            try:
                check(folder)
            except RunFolderBusy:
                temporary.unlink(missing_ok=True)
                raise
            os.replace(temporary, path)
        except OSError:                        # a file system without hard links
            os.replace(temporary, path)
        temporary.unlink(missing_ok=True)
        _held.add(key)


def release(folder):
    """Give ``folder``'s lock back (nothing if this process does not hold it)."""
    key = _key(folder)
    with _guard:
        if key not in _held:
            return
        _held.discard(key)
        path = Path(folder) / LOCK_FILE
        try:
            mine = path.read_text().split()[:2] == [str(os.getpid()), socket.gethostname()]
        except OSError:
            return
        if mine:
            path.unlink(missing_ok=True)


def _key(folder):
    return str(Path(folder).resolve())


def _started_after(pid, path):
    """Whether process ``pid`` started after the lock file ``path`` was written (so it is not the
    run that wrote it: its id was used again), where /proc says when processes started."""
    try:
        ticks = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[19])
        boot = next(float(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines()
                    if line.startswith("btime"))
        return boot + ticks / os.sysconf("SC_CLK_TCK") > path.stat().st_mtime + 2.0
    except (OSError, ValueError, IndexError, StopIteration):
        return False


def _alive(pid):
    """Whether process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:                    # another user's process
        return True
    except OSError:
        return False
    return True
