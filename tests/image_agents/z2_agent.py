"""An AIDO-z2 lane-following agent node for container images built in the tests (cbor2 only: Debian's
python3-cbor2 in the image, never the host's Python).

``python3 z2_agent.py [MODE]``: answers the protocol, driving gently forward. Before answering it checks that it
runs on the image's own interpreter (``/usr/bin/python3`` of Debian, no proxybench importable) and exits 5 if not
(MODE ``anywhere``: no such check, for the benchmark's package of the same agent).
MODE ``daemon``: first forks a daemon (double fork, new session) that sleeps for good, as a careless ENTRYPOINT
does; the sandbox must end it with the episode.
"""

import importlib.util
import os
import sys
import time

import cbor2

DESCRIPTION = {"data": {"inputs": {t: {} for t in ("seed", "episode_start", "observations", "get_commands")},
                        "outputs": {"commands": {}}, "language": "", "description": "an agent in an image"},
               "meta": {}}


def _own_interpreter():
    if sys.executable != "/usr/bin/python3" or importlib.util.find_spec("proxybench") is not None:
        sys.stderr.write(f"not the image's interpreter: {sys.executable}\n")
        sys.exit(5)


def _daemon():
    if os.fork() == 0:
        os.setsid()
        if os.fork() == 0:
            sys.stdin.close()
            time.sleep(100000)
        os._exit(0)
    os.wait()


def _streams():
    """stdin/stdout, or the FIFOs AIDONODE_DATA_IN / AIDONODE_DATA_OUT name (made by the caller)."""
    path_in, path_out = os.environ.get("AIDONODE_DATA_IN"), os.environ.get("AIDONODE_DATA_OUT")
    if not path_in:
        return sys.stdin.buffer, sys.stdout.buffer
    out = path_out[5:] if path_out.startswith("fifo:") else path_out
    if not os.path.exists(out):
        os.mkfifo(out)
    return open(path_in, "rb", buffering=0), open(out, "wb")


def main():
    if sys.argv[1:] != ["anywhere"]:
        _own_interpreter()
    if sys.argv[1:] == ["daemon"]:
        _daemon()
    fin, fout = _streams()

    def send(*msgs):
        fout.write(b"".join(cbor2.dumps(m) for m in msgs))
        fout.flush()

    decoder = cbor2.CBORDecoder(fin)
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return
        out = []
        if msg.get("control") == "capabilities":
            out = [{"control": "capabilities", "data": {"z2": {"protocol-reflection": True}}}]
        elif msg.get("topic") == "wrapper.describe_protocol":
            out = [{"compat": ["z2"], "topic": "protocol_description", "data": DESCRIPTION, "timing": None}]
        elif msg.get("topic") == "get_commands":
            wheels = {"motor_left": 0.3, "motor_right": 0.3}
            out = [{"compat": ["z2"], "topic": "commands", "data": {"wheels": wheels}, "timing": None}]
        send({"control": "understood", "data": None}, *out, {"control": "over", "data": None})


if __name__ == "__main__":
    main()
