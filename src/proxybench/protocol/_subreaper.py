"""Run a program and leave nothing it started behind: ``python -I -S _subreaper.py ERRFD -- ARGV...``.

A node or an SDK program runs in a process group of its own, which the caller kills whole; but a program may start
a daemon that leaves the group (``setsid``, a double fork), and that daemon outlived the run (issue 38 item 3).
This launcher (standard library only, no proxybench import, so it starts in milliseconds) is the program's parent
and a *child subreaper* (``prctl(PR_SET_CHILD_SUBREAPER)``): whatever the program forks and orphans is re-parented
to it rather than to init, so it always knows the whole tree. It ends when the program has ended *and* every
descendant is gone:

- the program exits: every descendant left is killed (``SIGKILL``) and reaped; the launcher exits as the program did
  (same code, or the same signal);
- ``SIGTERM`` (the caller's polite stop): ``SIGTERM`` to every descendant, ``GRACE_S`` for the program to end, then
  ``SIGKILL`` to whatever is left;
- ``SIGUSR1`` (the caller's hard stop), or the caller's death: ``SIGKILL`` to every descendant at once.

``ERRFD`` (inherited, close-on-exec in the program): ``P<pid>`` of the program is written there, and if the program
cannot be executed its ``E<errno>``, so the caller raises the ``OSError`` that ``subprocess`` would have. The program
dies with the launcher (``PR_SET_PDEATHSIG``), should the launcher itself be killed.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import resource
import select
import signal
import sys
import time

PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36
GRACE_S = 0.5
#: a tree that keeps forking while it is being killed is given up on after this long (the caller kills the group)
KILL_DEADLINE_S = 10.0

_stop: int | None = None  # the signal that asked us to stop


def _on_signal(signum: int, _frame: object) -> None:
    global _stop
    _stop = signum if _stop is None or signum == signal.SIGUSR1 else _stop


def descendants(root: int) -> list[int]:
    """Every process below ``root`` (from the parent ids in ``/proc``), nearest first."""
    children: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as f:
                ppid = int(f.read().rsplit(b")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue  # ended meanwhile
        children.setdefault(ppid, []).append(int(name))
    out, todo = [], [root]
    while todo:
        for pid in children.get(todo.pop(), ()):
            out.append(pid)
            todo.append(pid)
    return out


def _signal_all(sig: int) -> None:
    for pid in descendants(os.getpid()):
        with contextlib.suppress(OSError):
            os.kill(pid, sig)


def _reap(program: int, status: list[int]) -> bool:
    """Reap every child that has ended (keeping the program's status); whether any child is left."""
    while True:
        try:
            pid, st = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return False
        if pid == 0:
            return True
        if pid == program:
            status.append(st)


def _kill_tree(program: int, status: list[int]) -> None:
    """``SIGKILL`` every descendant and reap them, again until none is left (orphans of the killed come to us)."""
    deadline = time.monotonic() + KILL_DEADLINE_S
    while time.monotonic() < deadline:
        _signal_all(signal.SIGKILL)
        if not _reap(program, status):
            return
        time.sleep(0.005)


def _exit_like(status: int) -> None:
    """End as the program ended: its exit code, or the signal that killed it."""
    if os.WIFSIGNALED(status):
        sig = os.WTERMSIG(status)
        with contextlib.suppress(ValueError, OSError):  # SIGKILL and SIGSTOP have no handler to reset
            signal.signal(sig, signal.SIG_DFL)
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # the program dumped its core already, if any
        os.kill(os.getpid(), sig)
    sys.exit(os.WEXITSTATUS(status) if os.WIFEXITED(status) else 1)


def _start(argv: list[str], err_fd: int, libc: ctypes.CDLL) -> int:
    """Fork and execute the program; ``P<pid>`` goes to ``err_fd``, and from the child an exec failure's
    ``E<errno>``. The program is killed by the kernel if this launcher dies (``PR_SET_PDEATHSIG``)."""
    os.set_inheritable(err_fd, False)  # closed in the program when it is executed
    me = os.getpid()
    pid = os.fork()
    if pid == 0:
        try:
            for sig in (signal.SIGPIPE, signal.SIGXFSZ, signal.SIGTERM, signal.SIGUSR1, signal.SIGCHLD,
                        signal.SIGHUP, signal.SIGINT):
                signal.signal(sig, signal.SIG_DFL)
            signal.set_wakeup_fd(-1)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
            if os.getppid() != me:  # the launcher died before that
                os._exit(127)
            os.execvp(argv[0], argv)
        except OSError as exc:
            os.write(err_fd, f"E{exc.errno or 0}\n".encode())
        finally:
            os._exit(127)
    os.write(err_fd, f"P{pid}\n".encode())
    os.close(err_fd)
    null = os.open(os.devnull, os.O_RDWR)  # the streams are the program's: its end of them ends the caller's read
    for fd in (0, 1):
        os.dup2(null, fd)
    os.close(null)
    return pid


def main(args: list[str]) -> None:
    err_fd, sep, argv = int(args[0]), args[1], args[2:]
    if sep != "--" or not argv:
        sys.exit("usage: _subreaper.py ERRFD -- ARGV...")
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) != 0:
        sys.exit(f"_subreaper: prctl(PR_SET_CHILD_SUBREAPER): {os.strerror(ctypes.get_errno())}")
    parent = os.getppid()
    try:
        parent_fd: int | None = os.pidfd_open(parent)
    except (OSError, AttributeError):
        parent_fd = None
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    for sig in (signal.SIGTERM, signal.SIGUSR1, signal.SIGCHLD, signal.SIGHUP, signal.SIGINT):
        signal.signal(sig, _on_signal if sig != signal.SIGCHLD else (lambda *_: None))
    program = _start(argv, err_fd, libc)
    status: list[int] = []
    while not status and _stop is None:
        watch = [wake_r] + ([parent_fd] if parent_fd is not None else [])
        ready = select.select(watch, [], [], 1.0)[0]
        if wake_r in ready:
            os.read(wake_r, 512)
        if (parent_fd is not None and parent_fd in ready) or os.getppid() != parent:
            _on_signal(signal.SIGUSR1, None)  # the caller is gone: nobody will stop the program
        _reap(program, status)
    if not status and _stop in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        _signal_all(signal.SIGTERM)
        deadline = time.monotonic() + GRACE_S
        while not status and _stop != signal.SIGUSR1 and time.monotonic() < deadline:
            if select.select([wake_r], [], [], max(0.0, min(0.05, deadline - time.monotonic())))[0]:
                os.read(wake_r, 512)
            _reap(program, status)
    _kill_tree(program, status)
    _exit_like(status[0] if status else signal.SIGKILL)  # a program we killed ended by SIGKILL


if __name__ == "__main__":
    main(sys.argv[1:])
