"""An SDK agent package's program that checks its sandbox before it drives (as lane.py): it exits with 3 if it
sees a process outside its sandbox (the virtual robot's bridge), with 4 if it reaches the host's network
(argv[1]: a port the test listens on), with 5 if the virtual robot is not on its loopback at 127.0.0.1:7501."""
import os
import socket
import sys

for pid in filter(str.isdigit, os.listdir("/proc")):
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            seen = f.read()
    except OSError:
        continue
    if b"bridge.py" in seen or b"pytest" in seen:
        print(f"sees a host process: {seen[:200]!r}", file=sys.stderr)
        sys.exit(3)
try:
    socket.create_connection(("127.0.0.1", int(sys.argv[1])), timeout=2).close()
    print("reached the host's network", file=sys.stderr)
    sys.exit(4)
except OSError:
    pass
try:
    socket.create_connection(("127.0.0.1", 7501), timeout=5).close()
except OSError as exc:
    print(f"no virtual robot at 127.0.0.1:7501: {exc}", file=sys.stderr)
    sys.exit(5)
with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "lane.py")) as f:
    exec(compile(f.read(), "lane.py", "exec"))
