"""Exec shim that confines an agent node: ``python -I -S _confine.py [options] -- ARGV...``.

Run as a script (standard library only, no proxybench import, so it starts in milliseconds) between the
network isolation (``unshare`` / ``bwrap``) and the agent's own command. In this order it changes into
the agent's folder, sets resource limits, drops root to an unprivileged user when asked, forbids gaining
privileges again, asks the kernel to kill it when its parent dies, and then replaces itself with the agent
command under a clean environment, so the process the caller kills is the agent itself.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import signal
import sys

PR_SET_PDEATHSIG = 1
PR_SET_NO_NEW_PRIVS = 38

_LIMITS = (("cpu", resource.RLIMIT_CPU), ("memory", resource.RLIMIT_AS), ("fsize", resource.RLIMIT_FSIZE),
           ("nproc", resource.RLIMIT_NPROC), ("core", resource.RLIMIT_CORE))


def _set_limit(which: int, soft: int, hard: int) -> None:
    """Lower a limit; never try to raise it above the current hard limit (which would fail)."""
    _, cur_hard = resource.getrlimit(which)
    if cur_hard != resource.RLIM_INFINITY:
        soft, hard = min(soft, cur_hard), min(hard, cur_hard)
    resource.setrlimit(which, (soft, hard))


def _prctl(option: int, arg: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(option, arg, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), f"prctl({option}) failed")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="_confine")
    p.add_argument("--cwd", required=True)
    for name, _ in _LIMITS:
        p.add_argument(f"--{name}", type=int)
    p.add_argument("--uid", type=int)
    p.add_argument("--gid", type=int)
    p.add_argument("--parent", type=int, help="exit at once unless this is still our parent process")
    p.add_argument("--env", action="append", default=[], help="KEY=VALUE for the agent's environment")
    p.add_argument("command", nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        print("_confine: no command given", file=sys.stderr)
        return 2
    try:
        os.chdir(args.cwd)
        for name, which in _LIMITS:
            value = getattr(args, name)
            if value is not None:
                _set_limit(which, value, value + 5 if name == "cpu" else value)  # CPU: SIGXCPU, then SIGKILL
        if args.gid is not None:
            os.setgroups([])
            os.setgid(args.gid)
        if args.uid is not None:
            os.setuid(args.uid)
        _prctl(PR_SET_NO_NEW_PRIVS, 1)
        _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)  # after setuid: a credential change clears it
        if args.parent is not None and os.getppid() != args.parent:
            return 3  # the caller is already gone
    except OSError as exc:
        print(f"_confine: cannot confine the agent: {exc}", file=sys.stderr)
        return 126
    env = dict(item.split("=", 1) for item in args.env if "=" in item)
    try:
        os.execvpe(command[0], command, env)
    except OSError as exc:
        print(f"_confine: cannot start {command[0]!r}: {exc}", file=sys.stderr)
        return 127
    return 0  # unreachable: exec replaced this process


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
