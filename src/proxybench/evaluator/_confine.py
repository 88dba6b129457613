"""Exec shim that starts an agent node in its sandbox: ``python -I -S _confine.py [options] -- ARGV...``.

Run as a script (standard library only, no proxybench import, so it starts in milliseconds) by the job's
worker; it ends as the guard of bubblewrap (or, in the developer's unsafe mode without bubblewrap, by
``exec``-ing the agent itself); the caller kills its process group. In this order it:

1. opens every folder the agent may see (the runtime and the package) while it can still reach them;
2. as root: stages them in a private mount namespace, on a fresh ``/tmp`` of its own, where the agent
   user can reach them (the runtime may sit under a home folder only root may enter, e.g. a pyenv
   Python in /root; the evaluator's own folders stay unreachable);
3. sets the resource limits (before the user switch, so that RLIMIT_NPROC also bounds the user
   namespace bubblewrap creates), drops to the agent user (no supplementary groups), makes it the first
   choice of the kernel's out-of-memory killer, forbids gaining privileges again, and asks the kernel to
   kill it when the worker dies;
4. starts ``bwrap`` and stays beside it as its guard (see ``_guard``). bwrap makes new user, PID, network,
   IPC, UTS and cgroup namespaces, drops every capability, forbids further user namespaces, starts a new
   session, and shows a read-only view of only ``/usr``, the runtime and the package (at ``/agent``),
   bounded tmpfs for ``/scratch`` (``$HOME``), ``/tmp`` and ``/dev/shm``, its own ``/proc`` and ``/dev``,
   a read-only root, and a clean environment.

With ``--join-netns-env VAR`` (a duckietown-sdk package, docs/dtps.md) the shim, still root, joins the
network namespace named in ``$VAR`` (``/proc/PID/ns/net`` of the virtual robot's bridge, which made it and
runs there as another user) and bwrap shares it instead of making an empty one: the agent reaches the robot
on that namespace's loopback and nothing else, and sees no process of the host. With ``--host-net`` (the
developer's unsafe mode only) bwrap keeps the host's network.

With ``--rootfs`` (a container image, docs/evaluator.md) the package folder is the image's root file system:
bwrap shows it read-only as ``/`` instead of the host's ``/usr`` and the runtime, with its own ``/proc``, ``/dev``,
bounded tmpfs for ``/tmp``, ``/dev/shm`` and ``/scratch``, starts in ``--chdir``, and gives the agent the image's
user id inside its user namespace (``--inside-uid``; outside it is still the agent user, with no capability).

With ``--fifo-root ROOT`` (the node's FIFO transport) the caller has made a folder directly in ROOT
holding the two FIFOs and named them in ``AIDONODE_DATA_IN`` / ``AIDONODE_DATA_OUT``; that one folder,
checked, is shown read-only at ``/fifo`` (a FIFO on a read-only mount can still be opened both ways) and
the two variables, pointing there, are the only ones passed through.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import resource
import signal
import stat
import sys

PR_SET_PDEATHSIG = 1
PR_SET_NO_NEW_PRIVS = 38
CLONE_NEWNS = 0x00020000
CLONE_NEWNET = 0x40000000
MS_RDONLY, MS_NOSUID, MS_NODEV, MS_BIND, MS_REMOUNT, MS_REC, MS_PRIVATE = 1, 2, 4, 4096, 32, 16384, 1 << 18
STAGE = "/tmp"  # over-mounted in the shim's private mount namespace only
PACKAGE_AT = "/agent"
SCRATCH_AT = "/scratch"
FIFO_AT = "/fifo"
ENV_DATA_IN, ENV_DATA_OUT = "AIDONODE_DATA_IN", "AIDONODE_DATA_OUT"  # as proxybench.protocol.wire (not imported)
#: host files the dynamic linker and the C library read; nothing else of /etc is visible
ETC_FILES = ("/etc/ld.so.cache", "/etc/ld.so.conf", "/etc/ld.so.conf.d", "/etc/localtime", "/etc/alternatives")
ROOT_LINKS = ("/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32")

_LIMITS = (("cpu", resource.RLIMIT_CPU), ("memory", resource.RLIMIT_AS), ("fsize", resource.RLIMIT_FSIZE),
           ("nproc", resource.RLIMIT_NPROC), ("core", resource.RLIMIT_CORE))
_libc = ctypes.CDLL(None, use_errno=True)


def _check(ret: int, what: str) -> None:
    if ret != 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"{what}: {os.strerror(errno)}")


def _enc(text: str | None) -> bytes | None:
    return None if text is None else text.encode()


def _mount(source: str | None, target: str, fstype: str | None, flags: int, data: str | None = None) -> None:
    _check(_libc.mount(_enc(source), _enc(target), _enc(fstype), ctypes.c_ulong(flags), _enc(data)),
           f"mount {source} on {target}")


def _set_limit(which: int, soft: int, hard: int) -> None:
    """Lower a limit; never try to raise it above the current hard limit (which would fail)."""
    _, cur_hard = resource.getrlimit(which)
    if cur_hard != resource.RLIM_INFINITY:
        soft, hard = min(soft, cur_hard), min(hard, cur_hard)
    resource.setrlimit(which, (soft, hard))


def _prctl(option: int, arg: int) -> None:
    _check(_libc.prctl(option, arg, 0, 0, 0), f"prctl({option})")


def _stage(sources: list[str]) -> list[str]:
    """Bind ``sources`` under a fresh tmpfs on ``/tmp`` of a private mount namespace; the staged paths, which
    the agent user can reach. The sources are opened before ``/tmp`` is covered (one may lie under it)."""
    _check(_libc.unshare(CLONE_NEWNS), "unshare(CLONE_NEWNS)")
    _mount(None, "/", None, MS_REC | MS_PRIVATE)  # nothing of this namespace leaks back to the host
    fds = [os.open(s, os.O_PATH | os.O_DIRECTORY | os.O_CLOEXEC) for s in sources]  # of this namespace
    _mount("proxybench-stage", STAGE, "tmpfs", MS_NOSUID | MS_NODEV, "mode=0755,size=1m")
    staged = []
    for i, fd in enumerate(fds):
        target = f"{STAGE}/{i}"
        os.mkdir(target, 0o755)
        _mount(f"/proc/self/fd/{fd}", target, None, MS_BIND | MS_REC)
        _mount(None, target, None, MS_BIND | MS_REMOUNT | MS_RDONLY | MS_NOSUID | MS_NODEV)
        os.close(fd)
        staged.append(target)
    return staged


class Refused(ValueError):
    """The caller asked for something this shim will not show the agent."""


def _fifo_folder(root: str) -> str | None:
    """The node's FIFO folder named by ``AIDONODE_DATA_IN`` / ``_OUT`` (None: no FIFO transport), checked to be
    a real folder directly inside ``root`` that holds the two FIFOs ``in`` and ``out``."""
    data_in, data_out = os.environ.get(ENV_DATA_IN), os.environ.get(ENV_DATA_OUT)
    if data_in is None and data_out is None:
        return None
    folder = os.path.dirname(data_in or "")
    if not (data_in and os.path.basename(data_in) == "in" and data_out == f"fifo:{folder}/out"):
        raise Refused(f"{ENV_DATA_IN} / {ENV_DATA_OUT} must be FOLDER/in and fifo:FOLDER/out, got {data_in!r}, "
                      f"{data_out!r}")
    real_root = os.path.realpath(root)
    if os.path.realpath(folder) != os.path.join(real_root, os.path.basename(folder)) or \
            not stat.S_ISDIR(os.lstat(folder).st_mode):
        raise Refused(f"the FIFO folder {folder!r} is not a folder directly inside --fifo-root {root!r}")
    for name in ("in", "out"):
        if not stat.S_ISFIFO(os.lstat(os.path.join(folder, name)).st_mode):
            raise Refused(f"{os.path.join(folder, name)!r} is not a FIFO")
    return os.path.join(real_root, os.path.basename(folder))


def _parent_alive(parent: int) -> bool:
    """Whether ``parent`` still runs us: our parent, or our parent's parent where proxybench's subreaper launcher
    (``protocol/_subreaper.py``, which kills everything below it when the caller dies) stands between."""
    ppid = os.getppid()
    if ppid == parent:
        return True
    try:
        with open(f"/proc/{ppid}/stat", "rb") as f:
            return int(f.read().rsplit(b")", 1)[1].split()[1]) == parent
    except (OSError, IndexError, ValueError):
        return False


def _join_netns(variable: str) -> None:
    """Join the network namespace ``/proc/PID/ns/net`` named in ``$variable`` (as root, before the user switch)."""
    path = os.environ.get(variable, "")
    parts = path.split("/")
    if not (len(parts) == 5 and parts[:2] == ["", "proc"] and parts[2].isdigit() and parts[3:] == ["ns", "net"]):
        raise Refused(f"${variable} must name /proc/PID/ns/net, got {path!r}")
    fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    try:
        _check(_libc.setns(fd, CLONE_NEWNET), f"setns({path})")
    finally:
        os.close(fd)


def _data_fd(text: str) -> str:
    fd = os.memfd_create("proxybench-etc", 0)
    os.write(fd, text.encode())
    os.lseek(fd, 0, os.SEEK_SET)
    os.set_inheritable(fd, True)
    return str(fd)


def _bwrap_argv(args: argparse.Namespace, runtime: list[tuple[str, str]], package: str, fifo: str | None,
                env: dict[str, str], uid: int, gid: int) -> list[str]:
    net = [] if args.join_netns_env or args.host_net else ["--unshare-net"]
    argv = [args.bwrap, "--unshare-user", "--unshare-pid", *net, "--unshare-ipc", "--unshare-uts",
            "--unshare-cgroup-try", "--disable-userns", "--die-with-parent", "--new-session", "--cap-drop", "ALL",
            "--hostname", "sandbox", "--clearenv"]
    for key, value in env.items():
        argv += ["--setenv", key, value]
    if args.rootfs:
        return argv + _rootfs_mounts(args, package, fifo)
    argv += ["--ro-bind", "/usr", "/usr"]
    for link in ROOT_LINKS:
        if os.path.islink(link):
            argv += ["--symlink", os.readlink(link), link]
        elif os.path.isdir(link):
            argv += ["--ro-bind", link, link]
    for path in ETC_FILES:
        argv += ["--ro-bind-try", path, path]
    user = f"agent:x:{uid}:{gid}:agent:{SCRATCH_AT}:/usr/sbin/nologin\n"
    argv += ["--ro-bind-data", _data_fd(user), "/etc/passwd",
             "--ro-bind-data", _data_fd(f"agent:x:{gid}:\n"), "/etc/group",
             "--proc", "/proc", "--dev", "/dev",
             "--perms", "1777", "--size", str(args.tmp), "--tmpfs", "/tmp",
             "--perms", "1777", "--size", str(args.tmp), "--tmpfs", "/dev/shm",
             "--perms", "0700", "--size", str(args.scratch), "--tmpfs", SCRATCH_AT]
    for source, dest in runtime:  # after /tmp: a runtime under /tmp must not be covered by the private one
        argv += ["--ro-bind", source, dest]
    if fifo is not None:
        argv += ["--ro-bind", fifo, FIFO_AT]
    argv += ["--ro-bind", package, PACKAGE_AT, "--remount-ro", "/", "--chdir", PACKAGE_AT, "--"]
    return argv


def _rootfs_mounts(args: argparse.Namespace, rootfs: str, fifo: str | None) -> list[str]:
    """A container image's root file system as ``/`` (read-only; the mount points exist in it), its own ``/proc``,
    ``/dev`` and tmpfs, the user the image names (inside the user namespace only) and its working directory."""
    argv = ["--uid", str(args.inside_uid), "--gid", str(args.inside_gid)] if args.inside_uid is not None else []
    argv += ["--ro-bind", rootfs, "/", "--proc", "/proc", "--dev", "/dev",
             "--perms", "1777", "--size", str(args.tmp), "--tmpfs", "/tmp",
             "--perms", "1777", "--size", str(args.tmp), "--tmpfs", "/dev/shm",
             "--perms", "0777", "--size", str(args.scratch), "--tmpfs", SCRATCH_AT]
    if fifo is not None:
        argv += ["--ro-bind", fifo, FIFO_AT]
    return [*argv, "--chdir", args.chdir or "/", "--"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="_confine")
    p.add_argument("--package", required=True, help="the unpacked agent package (read-only at /agent)")
    p.add_argument("--runtime", action="append", default=[], help="a folder of the runtime (read-only, same path)")
    for name, _ in _LIMITS:
        p.add_argument(f"--{name}", type=int)
    p.add_argument("--scratch", type=int, default=256 << 20, help="bytes of /scratch")
    p.add_argument("--tmp", type=int, default=64 << 20, help="bytes of /tmp and of /dev/shm, each")
    p.add_argument("--uid", type=int, help="the agent user (needs root): the sandbox runs as this user")
    p.add_argument("--gid", type=int)
    p.add_argument("--bwrap", help="bubblewrap executable; without it: no namespaces (developer's unsafe mode)")
    p.add_argument("--parent", type=int, help="exit at once unless this is still our parent process (or the parent "
                                              "of proxybench's subreaper launcher that started us)")
    p.add_argument("--env", action="append", default=[], help="KEY=VALUE for the agent's environment")
    p.add_argument("--fifo-root", help="FIFO transport: the folder in which the caller makes each node's FIFO folder")
    p.add_argument("--join-netns-env", help="join the network namespace /proc/PID/ns/net named in this variable (root)")
    p.add_argument("--host-net", action="store_true", help="keep the host's network (developer's unsafe mode)")
    p.add_argument("--rootfs", action="store_true", help="--package is a container image's root file system: run in it")
    p.add_argument("--chdir", help="with --rootfs: the working directory inside it")
    p.add_argument("--inside-uid", type=int, help="with --rootfs: the user id the agent has inside its namespace")
    p.add_argument("--inside-gid", type=int)
    p.add_argument("command", nargs=argparse.REMAINDER)
    return p


def main(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        print("_confine: no command given", file=sys.stderr)
        return 2
    env = dict(item.split("=", 1) for item in args.env if "=" in item)
    try:
        if args.join_netns_env:
            _join_netns(args.join_netns_env)
        fifo = _fifo_folder(args.fifo_root) if args.fifo_root else None
        if args.bwrap and args.uid is not None:
            staged = _stage([*args.runtime, args.package, *([fifo] if fifo else [])])
            runtime, package = list(zip(staged, args.runtime, strict=False)), staged[len(args.runtime)]
            fifo_view = staged[-1] if fifo else None
        else:
            runtime, package, fifo_view = [(r, r) for r in args.runtime], args.package, fifo
        if fifo is not None:  # the node finds its FIFOs where it sees them
            at = FIFO_AT if args.bwrap else fifo
            env.update({ENV_DATA_IN: f"{at}/in", ENV_DATA_OUT: f"fifo:{at}/out"})
        for name, which in _LIMITS:
            value = getattr(args, name)
            if value is not None:
                _set_limit(which, value, value + 5 if name == "cpu" else value)  # CPU: SIGXCPU, then SIGKILL
        with open("/proc/self/oom_score_adj", "w") as f:  # out of memory: the agent goes first, not the worker
            f.write("1000")
        if args.uid is not None:
            os.setgroups([])
            os.setgid(args.gid if args.gid is not None else args.uid)
            os.setuid(args.uid)
        _prctl(PR_SET_NO_NEW_PRIVS, 1)
        _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)  # after setuid: a credential change clears it
        if args.parent is not None and not _parent_alive(args.parent):
            return 3  # the worker is already gone
        if args.bwrap:
            command = _bwrap_argv(args, runtime, package, fifo_view, env, os.getuid(), os.getgid()) + command
            env = {}
        else:
            os.chdir(package)
    except (OSError, Refused) as exc:
        print(f"_confine: cannot confine the agent: {exc}", file=sys.stderr)
        return 126
    if args.bwrap:
        return _guard(command, env, args.parent)
    try:
        os.execvpe(command[0], command, env)
    except OSError as exc:
        print(f"_confine: cannot start {command[0]!r}: {exc}", file=sys.stderr)
        return 127
    return 0  # unreachable: exec replaced this process


def _guard(command: list[str], env: dict[str, str], parent: int | None) -> int:
    """Run bubblewrap as a child and stay beside it as its guard; bwrap's exit status is returned.

    bwrap's ``--die-with-parent`` can leave the sandbox's PID 1 behind: a killed evaluator once left one
    sleeping for good, re-parented to init (the worker died while bwrap was between its steps). The guard
    runs as the agent user, in a process group of its own with bwrap and the sandbox's PID 1 (bwrap does
    not change it), dies with the worker by a signal it can catch, and then kills the whole group: killing
    the sandbox's PID 1 ends every process in the sandbox's PID namespace.
    """
    with contextlib.suppress(PermissionError):  # a session leader (as the worker starts us) has its own group
        os.setpgid(0, 0)  # otherwise: never share the caller's group
    me = os.getpid()
    child = os.fork()
    if child == 0:
        try:
            _prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
            if os.getppid() != me:
                os._exit(3)
            os.execvpe(command[0], command, env)
        except OSError as exc:
            print(f"_confine: cannot start {command[0]!r}: {exc}", file=sys.stderr)
        os._exit(127)

    devnull = os.open(os.devnull, os.O_RDWR)  # the node's pipes are bwrap's: the worker sees EOF when it ends
    os.dup2(devnull, 0)
    os.dup2(devnull, 1)

    def end(_signum: int = 0, _frame: object = None) -> None:
        os.killpg(os.getpgrp(), signal.SIGKILL)  # bwrap, the sandbox's PID 1 and this guard

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, end)
    _prctl(PR_SET_PDEATHSIG, signal.SIGTERM)  # the worker gone: end(), which a SIGKILL could not run
    if parent is not None and not _parent_alive(parent):
        end()
    _, status = os.waitpid(child, 0)  # retried after a handler that returns (PEP 475)
    code = os.waitstatus_to_exitcode(status)
    if code < 0:  # bwrap was killed: so is this process, by the same signal
        signal.signal(-code, signal.SIG_DFL)
        os.kill(me, -code)
    return code


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
