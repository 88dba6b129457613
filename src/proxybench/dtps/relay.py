"""A relay to one robot: how a sandboxed SDK agent reaches a lab's DTPS robot, and nothing else.

An SDK agent finds its robot at ``127.0.0.1:7501`` (the Duckiematrix's address). For a virtual robot the bridge
serves there in a network namespace of its own and the agent's sandbox joins that namespace. A lab's DTPS robot
lives elsewhere (another machine, another process), and the sandbox must not get the host's network to reach it.
So the relay, a process of the evaluator's:

1. forks a **holder** that makes a network namespace of its own (only a loopback, up), binds ``127.0.0.1:PORT``
   there, hands the listening socket to its parent over a socketpair (``SCM_RIGHTS``), drops to ``--drop-to``
   and sleeps until the parent is gone: its ``/proc/PID/ns/net`` is the namespace the agent's sandbox joins
   (as for a virtual robot, :data:`~proxybench.dtps.agent.NETNS_ENV`);
2. stays in the host's namespace, drops to ``--drop-to`` too, and for every connection accepted on that socket
   opens one TCP connection to the robot's ``HOST:PORT`` and copies bytes both ways (at most ``--max-conns`` at
   once). Bytes, not HTTP: the agent speaks DTPS to the robot itself; the relay parses nothing of it.

So the agent's namespace holds a loopback and one listener, the relay, which can reach one address: the robot.
Without ``--own-netns`` (the developer's unsafe modes, where the agent shares the host's network) the relay
listens on the host's ``127.0.0.1:PORT``.

Run (root for ``--own-netns``): ``python -m proxybench.dtps.relay --to HOST:PORT [--port 7501] [--own-netns
--drop-to nobody]``; it prints one JSON line (``{"ready": true, "netns": …, "port": …}``) and relays until its
stdin ends or SIGTERM. :class:`RobotRelay` runs it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time

__all__ = ["RelayError", "RobotRelay", "main"]


class RelayError(RuntimeError):
    """The relay could not start or ended; one line."""


def _loopback_up() -> None:
    """Move this process into a network namespace of its own with its loopback up (root)."""
    import ctypes
    import fcntl
    import struct

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.unshare(0x40000000) != 0:  # CLONE_NEWNET
        err = ctypes.get_errno()
        raise OSError(err, f"unshare(CLONE_NEWNET): {os.strerror(err)} (a namespace of its own needs root)")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        flags = struct.unpack("16sH14x", fcntl.ioctl(s, 0x8913, struct.pack("16sH14x", b"lo", 0)))[1]
        fcntl.ioctl(s, 0x8914, struct.pack("16sH14x", b"lo", flags | 1))  # IFF_UP


def _drop_to(user: str) -> None:
    """Run on as ``user`` with no groups: the relay carries a stranger's bytes and needs no rights to do it."""
    if not user or os.geteuid() != 0:
        return
    import pwd

    pw = pwd.getpwnam(user)
    os.setgroups([])
    os.setgid(pw.pw_gid)
    os.setuid(pw.pw_uid)


def _holder(port: int, channel: socket.socket, user: str) -> None:
    """The forked holder (see the module): never returns."""
    try:
        _loopback_up()
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", port))
        listener.listen(64)
        socket.send_fds(channel, [b"L"], [listener.fileno()])
        listener.close()
        _drop_to(user)
        while channel.recv(1):  # until the relay is gone
            pass
    except BaseException as exc:  # a forked child reports and exits, never unwinds into the parent
        with contextlib.suppress(OSError):
            channel.sendall(f"E{type(exc).__name__}: {exc}"[:300].encode())
    finally:
        os._exit(0)


def _listener(port: int, own_netns: bool,
              user: str) -> tuple[socket.socket, str | None, socket.socket | None]:
    """(listening socket, the namespace's /proc path, the channel whose open end keeps the holder alive); the
    socket on the host without ``own_netns``."""
    if not own_netns:
        listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(("127.0.0.1", port))
        listener.listen(64)
        return listener, None, None
    parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    pid = os.fork()
    if pid == 0:
        parent.close()
        _holder(port, child, user)
    child.close()
    msg, fds, _, _ = socket.recv_fds(parent, 512, 1)
    if not fds:
        raise RelayError(f"the relay's namespace holder failed: {msg[1:].decode(errors='replace') or 'it ended'}")
    return socket.socket(fileno=fds[0]), f"/proc/{pid}/ns/net", parent


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(1 << 16):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


async def _serve(listener: socket.socket, host: str, port: int, max_conns: int) -> None:
    slots = asyncio.Semaphore(max_conns)
    done = asyncio.Event()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if slots.locked():
            writer.close()
            return
        async with slots:
            try:
                up_reader, up_writer = await asyncio.wait_for(asyncio.open_connection(host, port), 10.0)
            except (OSError, TimeoutError):
                writer.close()
                return
            await asyncio.gather(_pipe(reader, up_writer), _pipe(up_reader, writer))

    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, done.set)
    loop.add_reader(0, lambda: done.set() if not os.read(0, 4096) else None)
    server = await asyncio.start_server(handle, sock=listener)
    print(json.dumps({"ready": True}), flush=True)
    async with server:
        await done.wait()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m proxybench.dtps.relay", description=__doc__.splitlines()[0])
    p.add_argument("--to", required=True, help="the robot's HOST:PORT")
    p.add_argument("--port", type=int, default=7501, help="where the agent connects (127.0.0.1:PORT)")
    p.add_argument("--own-netns", action="store_true", help="listen in a network namespace of its own (root)")
    p.add_argument("--drop-to", default="", help="run on as this user once the socket is made")
    p.add_argument("--max-conns", type=int, default=64)
    args = p.parse_args(argv)
    host, _, port = args.to.rpartition(":")
    try:
        listener, netns, _holder_channel = _listener(args.port, args.own_netns, args.drop_to)
        _drop_to(args.drop_to)
    except (OSError, RelayError, KeyError) as exc:
        print(json.dumps({"ready": False, "error": f"{type(exc).__name__}: {exc}"[:300]}), flush=True)
        return 2
    print(json.dumps({"netns": netns, "port": args.port}), flush=True)
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(_serve(listener, host.strip("[]"), int(port), args.max_conns))
    return 0


class RobotRelay:
    """The relay process to the robot at ``host:port`` (see the module); ``netns``: the namespace an agent's
    sandbox joins (None without ``own_netns``: the relay listens on the host's 127.0.0.1:``listen``)."""

    def __init__(self, host: str, port: int, *, listen: int = 7501, own_netns: bool = True, user: str = "nobody",
                 start_timeout: float = 30.0):
        argv = [sys.executable, "-m", "proxybench.dtps.relay", "--to", f"{host}:{port}", "--port", str(listen)]
        if own_netns:
            argv += ["--own-netns", "--drop-to", user]
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     start_new_session=True, bufsize=0)  # unbuffered: select sees each line
        self.netns: str | None = None
        deadline = time.monotonic() + start_timeout
        for _ in range(2):  # the namespace line, then ready
            line = self._line(deadline)
            if line.get("ready") is False or "error" in line:
                self.close()
                raise RelayError(f"the relay to {host}:{port} did not start: {line.get('error')}")
            self.netns = line.get("netns", self.netns)

    def _line(self, deadline: float) -> dict:
        import select

        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
        raw = self.proc.stdout.readline() if ready else b""
        try:
            data = json.loads(raw)
        except ValueError:
            data = None
        if not isinstance(data, dict):
            err = b""
            if self.proc.poll() is not None and self.proc.stderr is not None:
                err = self.proc.stderr.read()[-300:]
            self.close()
            raise RelayError("the relay did not start" + (f": {err.decode(errors='replace').strip()}" if err else
                                                          " in time"))
        return data

    @property
    def alive(self) -> bool:
        return self.proc.poll() is None

    def close(self) -> None:
        """End the relay (its holder ends with it: the namespace goes once no sandbox is in it)."""
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for stream in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()

    def __enter__(self) -> RobotRelay:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


if __name__ == "__main__":
    sys.exit(main())
