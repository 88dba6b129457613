"""The operating-system side of an agent process: launch, pipes or FIFOs, stderr draining, kill and reap.

Kept apart from the protocol logic (:mod:`.process`) because every piece here exists to make failure
harmless: the node runs in its own process group so that killing it also kills whatever it spawned, and (on
Linux) under a subreaper launcher (``_subreaper.py``) so that what it forked out of its group (``setsid``
daemons) is killed at the end too;
stderr is drained by a thread into a bounded ring so a chatty node can never block on a full pipe; the
parent's ends of the streams are non-blocking, so every wait has a deadline.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import select
import shlex
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

from proxybench.protocol.wire import ENV_DATA_IN, ENV_DATA_OUT

__all__ = ["SHELL", "SUBREAPER", "Launch", "NotAFifo", "StderrDrain", "needs_shell", "node_argv"]

_PIPE_SIZE = 1 << 20  # a whole 640×480 observation fits in one write
#: the launcher that reaps whatever a program forks (run with this interpreter, ``-I -S``)
SUBREAPER = Path(__file__).with_name("_subreaper.py")
#: how long the launcher may take to end a program's tree (its grace for SIGTERM, then the kills)
_REAPER_WAIT_S = 3.0
#: the shell that runs command strings using shell syntax (``cd dir && exec node``)
SHELL = "/bin/sh"
_SHELL_CHARS = frozenset("|&;<>()$`*?[]~{}!#\n")
_SHELL_WORDS = frozenset({"cd", "exec", "export", "source", ".", "set", "ulimit", "umask", "eval", "unset",
                          "if", "for", "while", "case", "[[", "!"})


class NotAFifo(OSError):
    """The node's output path is a link or a file, not the FIFO it was to create (nothing else is read)."""


def needs_shell(cmd: str) -> bool:
    """Whether a command string uses shell syntax: operators, expansions, redirections, globs, builtins
    such as ``cd``, or ``VAR=value`` prefixes *outside quotes*. Plain ``prog 'arg with spaces'`` does not,
    so a string built with :func:`shlex.join` is still executed directly."""
    lexer = shlex.shlex(cmd, posix=False, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = ""
    try:
        tokens = list(lexer)
    except ValueError:  # an unclosed quote: let the shell report it
        return True
    for k, tok in enumerate(tokens):
        quoted = len(tok) >= 2 and tok[0] == tok[-1] and tok[0] in "'\""
        if quoted:
            if tok[0] == '"' and any(c in tok for c in "$`\\"):
                return True  # expansions happen inside double quotes
            continue
        if any(c in _SHELL_CHARS or c in "'\"" for c in tok):
            return True
        if k == 0 and (tok in _SHELL_WORDS or re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", tok)):
            return True
    return False


def node_argv(cmd: str | Sequence[str], shell: bool | None = None) -> list[str]:
    """The argv that starts a node. A list is used as is; a string runs through ``/bin/sh -c`` when
    ``shell`` is True, or when None (auto) and it uses shell syntax (:func:`needs_shell`), else it is split
    like a shell would. Either way the node starts in its own process group, which is killed whole."""
    if not isinstance(cmd, str):
        argv = [str(a) for a in cmd]
        if not argv:
            raise ValueError("empty node command")
        return argv
    if not cmd.strip():
        raise ValueError("empty node command")
    if shell or (shell is None and needs_shell(cmd)):
        return [SHELL, "-c", cmd]
    return shlex.split(cmd)


class StderrDrain:
    """Reads a stderr pipe in a daemon thread: keeps the last lines and counts bytes per request.

    When the bytes since :meth:`arm` exceed the limit, one byte is written to :attr:`wake_fd`'s pipe so
    that the caller, waiting in ``poll``, notices the flood at once.
    """

    def __init__(self, fd: int, lines: int = 50, line_chars: int = 2000,
                 on_line: Callable[[str], None] | None = None):
        self._fd = fd
        self._tail: deque[str] = deque(maxlen=lines)
        self._lock = threading.Lock()
        self._partial = bytearray()
        self._line_chars = line_chars
        self._on_line = on_line
        self._limit: int | None = None
        self._count = 0
        self._flagged = False
        self._done = False
        self._detached = False
        self._finished = False
        self.total_bytes = 0
        self.wake_fd, self._wake_w = os.pipe()
        os.set_blocking(self.wake_fd, False)
        os.set_blocking(self._wake_w, False)
        self._thread = threading.Thread(target=self._run, name=f"agent-stderr-{fd}", daemon=True)
        self._thread.start()

    def arm(self, limit: int | None) -> None:
        """Start counting a new request's bytes against ``limit``."""
        with self._lock:
            if self._flagged:
                with contextlib.suppress(BlockingIOError):
                    os.read(self.wake_fd, 64)
            self._limit, self._count, self._flagged = limit, 0, False

    def _run(self) -> None:
        while True:
            try:
                data = os.read(self._fd, 1 << 16)
            except OSError:
                break
            if not data:
                break
            self._callback(self._take(data))
        with self._lock:
            last = [self._emit(bytes(self._partial))] if self._partial else []
            self._partial.clear()
            self._done = True
            if self._detached:
                self._close_fds()
        self._callback(last)

    def _take(self, data: bytes) -> list[str]:
        """Count ``data``, flag a flood, add its complete lines to the tail; the new lines."""
        with self._lock:
            self.total_bytes += len(data)
            self._count += len(data)
            if self._limit is not None and self._count > self._limit and not self._flagged:
                self._flagged = True
                with contextlib.suppress(BlockingIOError):
                    os.write(self._wake_w, b"!")
            self._partial += data
            *lines, rest = self._partial.split(b"\n")
            self._partial = bytearray(rest[-self._line_chars:])
            return [self._emit(line) for line in lines[-(self._tail.maxlen or len(lines)):]]

    def _emit(self, line: bytes) -> str:
        text = line[: self._line_chars].decode("utf-8", "replace").rstrip("\r")
        self._tail.append(text)
        return text

    def _callback(self, lines: list[str]) -> None:
        """``on_line`` for each line, outside the lock (so the callback may call :meth:`tail`)."""
        if self._on_line is not None:
            for text in lines:
                with contextlib.suppress(Exception):
                    self._on_line(text)

    def tail(self) -> list[str]:
        with self._lock:
            lines = list(self._tail)
            if self._partial:
                lines.append(self._partial.decode("utf-8", "replace"))
        return lines

    def finish(self, timeout: float = 0.5) -> list[str]:
        """Wait (briefly) for the writers to be gone, then return the tail and close the pipes (once)."""
        if self._finished:
            return self.tail()
        self._finished = True
        self._thread.join(timeout)
        tail = self.tail()
        with self._lock:
            if not self._done:  # a grandchild still holds the pipe: the thread closes the fds when it ends
                self._detached = True
                return tail
        self._close_fds()
        return tail

    def _close_fds(self) -> None:
        for fd in (self._fd, self.wake_fd, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)


def _grow_pipe(fd: int) -> None:
    with contextlib.suppress(OSError, AttributeError):
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, _PIPE_SIZE)


class Launch:
    """One agent process and the parent's ends of its streams (``in_fd`` write, ``out_fd`` read); with transport
    ``"none"`` it has no protocol stream (both are -1) and its stdout goes to the stderr drain."""

    def __init__(self, argv: list[str], *, transport: str = "pipes", env: dict[str, str] | None = None,
                 cwd: str | None = None, stderr_lines: int = 50, on_stderr: Callable[[str], None] | None = None,
                 fifo_dir: str | None = None, reap: bool = True):
        if transport not in ("pipes", "fifos", "none"):
            raise ValueError(f"transport must be 'pipes', 'fifos' or 'none', not {transport!r}")
        self.transport = transport
        #: the process is the subreaper launcher, the program its child: see :meth:`terminate`
        self.reaped = reap and sys.platform == "linux"
        self._pass_fds: tuple[int, ...] = ()
        exec_r = -1
        if self.reaped:
            exec_r, exec_w = os.pipe()
            argv = [sys.executable, "-I", "-S", str(SUBREAPER), str(exec_w), "--", *argv]
            self._pass_fds = (exec_w,)
        self.fifo_dir = fifo_dir
        self.tmpdir: str | None = None
        self.dummy_fd: int | None = None
        self.out_fd = -1
        self.returncode: int | None = None
        full_env = {k: v for k, v in os.environ.items() if k not in (ENV_DATA_IN, ENV_DATA_OUT)}
        full_env.update(env or {})
        err_r, err_w = os.pipe()
        start = {"pipes": self._start_pipes, "fifos": self._start_fifos, "none": self._start_plain}[transport]
        try:
            self.proc = start(argv, full_env, cwd, err_w)
        except BaseException:
            os.close(err_r)
            self._cleanup_tmp()
            if exec_r >= 0:
                os.close(exec_r)
            raise
        finally:
            os.close(err_w)
            for fd in self._pass_fds:
                os.close(fd)
        #: the program's process id (with the launcher: its child; :attr:`proc` is the launcher)
        self.pid = self.proc.pid
        self.pidfd: int | None = None
        if exec_r >= 0:
            self._check_exec(exec_r, argv[6], err_r)
        self.stderr = StderrDrain(err_r, stderr_lines, on_line=on_stderr)
        with contextlib.suppress(OSError, AttributeError):
            self.pidfd = os.pidfd_open(self.proc.pid)

    def _check_exec(self, exec_r: int, program: str, err_r: int) -> None:
        """Raise the ``OSError`` that ``subprocess`` would have where the launcher could not execute ``program``
        (it writes the errno to ``exec_r``'s pipe; the pipe closes empty once the program runs)."""
        data = b""
        try:
            while select.select([exec_r], [], [], 30.0)[0] and (chunk := os.read(exec_r, 64)):
                data += chunk
        finally:
            os.close(exec_r)
        words = dict((w[:1], w[1:]) for w in data.decode("ascii", "replace").split() if w[1:].isdigit())
        if "P" in words:
            self.pid = int(words["P"])
        if "E" not in words:
            return
        self.terminate(0.0)
        os.close(err_r)
        code = int(words["E"])
        raise OSError(code, os.strerror(code) if code else "cannot execute", program)

    def _start_pipes(self, argv: list[str], env: dict, cwd: str | None, err_w: int) -> subprocess.Popen:
        in_r, in_w = os.pipe()
        out_r, out_w = os.pipe()
        for fd in (in_w, out_w):
            _grow_pipe(fd)
        try:
            proc = subprocess.Popen(argv, stdin=in_r, stdout=out_w, stderr=err_w, cwd=cwd, env=env,
                                    start_new_session=True, pass_fds=self._pass_fds)
        except BaseException:
            os.close(in_w)
            os.close(out_r)
            raise
        finally:
            os.close(in_r)
            os.close(out_w)
        self.in_fd, self.out_fd = in_w, out_r
        os.set_blocking(in_w, False)
        os.set_blocking(out_r, False)
        return proc

    def _start_plain(self, argv: list[str], env: dict, cwd: str | None, err_w: int) -> subprocess.Popen:
        """No protocol stream (a program that talks over the network, e.g. an SDK agent): stdout joins stderr."""
        self.in_fd = -1
        return subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=err_w, stderr=err_w, cwd=cwd, env=env,
                                start_new_session=True, pass_fds=self._pass_fds)

    def _start_fifos(self, argv: list[str], env: dict, cwd: str | None, err_w: int) -> subprocess.Popen:
        self.tmpdir = tempfile.mkdtemp(prefix="proxybench-node-", dir=self.fifo_dir)
        in_path = os.path.join(self.tmpdir, "in")
        self.out_path = os.path.join(self.tmpdir, "out")
        os.mkfifo(in_path, 0o600)
        if self.fifo_dir is not None:  # a shared folder (container mount, sandbox): the node may run as another
            os.mkfifo(self.out_path, 0o600)  # user and see the folder read-only, so both FIFOs are made here
            os.chmod(self.tmpdir, 0o755)  # (AIDO's nodes open an existing output FIFO); nothing else can be
            for path in (in_path, self.out_path):  # written to the folder
                os.chmod(path, 0o666)
        env.update({ENV_DATA_IN: in_path, ENV_DATA_OUT: "fifo:" + self.out_path})
        # read-write: opening never blocks, and the node's open for reading returns at once
        self.in_fd = os.open(in_path, os.O_RDWR | os.O_NONBLOCK)
        _grow_pipe(self.in_fd)
        try:
            return subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=err_w, stderr=err_w, cwd=cwd, env=env,
                                    start_new_session=True, pass_fds=self._pass_fds)
        except BaseException:
            os.close(self.in_fd)
            raise

    def output_ready(self) -> bool:
        """FIFOs: open the node's output once it has created it. Until the node's first byte arrives a
        spare write end stays open, so that reading before the node opens its end cannot look like EOF."""
        if self.out_fd >= 0:
            return True
        if not os.path.lexists(self.out_path):
            return False
        try:  # never follow a link the node may have put there, never read anything but a FIFO
            fd = os.open(self.out_path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
        except OSError as exc:
            raise NotAFifo(f"cannot open the node's output FIFO {self.out_path}: {exc.strerror}") from None
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            os.close(fd)
            raise NotAFifo(f"the node's output {self.out_path} is not a FIFO: refused")
        self.out_fd = fd
        try:  # the same FIFO, whatever its path names by now
            self.dummy_fd = os.open(f"/proc/self/fd/{fd}", os.O_WRONLY | os.O_NONBLOCK)
        except OSError:  # no /proc (macOS)
            self.dummy_fd = os.open(self.out_path, os.O_WRONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
        return True

    def got_output(self) -> None:
        if self.dummy_fd is not None:
            os.close(self.dummy_fd)
            self.dummy_fd = None

    def exited(self) -> bool:
        """Whether the process has ended (without reaping it, so its group id stays reserved)."""
        if self.returncode is not None:
            return True
        if not hasattr(os, "waitid"):  # macOS: reaping is the only way to know
            return self.proc.poll() is not None
        try:
            return os.waitid(os.P_PID, self.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
        except ChildProcessError:
            return True

    def wait_exit(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for the process to end by itself."""
        deadline = time.monotonic() + timeout
        while not self.exited():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            if self.pidfd is not None:
                select.select([self.pidfd], [], [], left)
            else:
                time.sleep(min(left, 0.005))
        return True

    def write(self, data: bytes, wait: Callable[[], None], closed: Callable[[], None]) -> None:
        """Write all of ``data`` to the process's (non-blocking) input: ``wait()`` while the pipe is full (the caller
        bounds the time and keeps reading the output, which the process may be blocked writing), ``closed()`` (it
        must raise) once the process no longer reads."""
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.in_fd, view):]
                continue
            except BlockingIOError:
                pass
            except OSError:
                closed()
            wait()

    def close_input(self) -> None:
        if self.in_fd >= 0:
            os.close(self.in_fd)
            self.in_fd = -1

    def _killpg(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.proc.pid, sig)

    def terminate(self, grace: float = 0.0, term_first: bool = False) -> int | None:
        """Let the process end by itself for ``grace`` s, then kill its whole group; reap; its exit status."""
        if self.returncode is not None:
            return self.returncode
        if not self.wait_exit(grace):
            if self.reaped:  # the launcher ends the program and every descendant, in or out of the group
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(self.proc.pid, signal.SIGTERM if term_first else signal.SIGUSR1)
                self.wait_exit(_REAPER_WAIT_S)
            elif term_first:
                self._killpg(signal.SIGTERM)
                self.wait_exit(0.5)
        self._killpg(signal.SIGKILL)  # the leader is at most a zombie here, so its group id is still ours
        with contextlib.suppress(subprocess.TimeoutExpired):  # stuck in the kernel even after SIGKILL: never hang
            self.returncode = self.proc.wait(timeout=10.0)
        self._release()
        return self.returncode

    def _release(self) -> None:
        for name in ("in_fd", "out_fd", "dummy_fd", "pidfd"):
            fd = getattr(self, name)
            if fd is not None and fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
            setattr(self, name, -1 if name in ("in_fd", "out_fd") else None)
        self._cleanup_tmp()

    def _cleanup_tmp(self) -> None:
        if self.tmpdir is not None:
            shutil.rmtree(self.tmpdir, ignore_errors=True)
            self.tmpdir = None

    def kill_quietly(self) -> None:
        """Last resort at garbage collection or interpreter exit: kill, reap, release every descriptor."""
        with contextlib.suppress(Exception):
            self.terminate()
            self.stderr.finish(timeout=0.0)
