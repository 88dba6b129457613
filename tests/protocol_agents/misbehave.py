"""A minimal AIDO agent node (cbor2 only, so it starts fast) that misbehaves on purpose.

``python misbehave.py MODE [TRIGGER]``: behaves until the first input whose topic (or control code) is
TRIGGER (default ``get_commands``), then does MODE instead of answering. The tests drive it with
AgentProcess and check the failure reason each MODE produces.
"""

import math
import os
import subprocess
import sys
import time

import cbor2


def _streams():
    """stdin/stdout, or the AIDONODE_DATA_IN / AIDONODE_DATA_OUT (``fifo:`` creates it) streams."""
    path_in, path_out = os.environ.get("AIDONODE_DATA_IN"), os.environ.get("AIDONODE_DATA_OUT")
    fin = open(path_in, "rb", buffering=0) if path_in else sys.stdin.buffer  # noqa: SIM115 - kept open
    if path_out and path_out.startswith("fifo:"):
        os.mkfifo(path_out[5:])
        path_out = path_out[5:]
    return fin, (open(path_out, "wb") if path_out else sys.stdout.buffer)


IN = OUT = None  # set by main()
DESCRIPTION = {"data": {"inputs": {t: {} for t in ("seed", "episode_start", "observations", "get_commands")},
                        "outputs": {"commands": {}}, "language": "", "description": "misbehaving node"},
               "meta": {}}


def send(*msgs):
    OUT.write(b"".join(cbor2.dumps(m) for m in msgs))
    OUT.flush()


def ctrl(code, data=None):
    return {"control": code, "data": data}


def topic(name, data):
    return {"compat": ["z2"], "topic": name, "data": data, "timing": None}


def commands(left, right):
    return topic("commands", {"wheels": {"motor_left": left, "motor_right": right}})


def hang():
    time.sleep(1000)


def misbehave(mode):
    if mode == "crash":
        sys.stderr.write("starting to fail\nboom: something broke\n")
        sys.stderr.flush()
        os._exit(3)
    if mode == "exit0":
        os._exit(0)
    if mode == "garbage":
        OUT.write(b"\x1c\x1d\x1e\xff\xfe")
    elif mode == "text":
        OUT.write(b"hello from the agent, printing to stdout\n")
    elif mode == "not-a-map":
        OUT.write(cbor2.dumps([1, 2, 3]))
    elif mode == "truncated":
        OUT.write(cbor2.dumps(ctrl("understood"))[:9])
        OUT.flush()
        os._exit(0)
    elif mode == "bad-message":
        send({"hello": 1})
    elif mode == "unknown-topic":
        send(ctrl("understood"), topic("banana", 1), ctrl("over"))
    elif mode == "not-understood":
        send(ctrl("not-understood", 'Input channel "get_commands" not found in protocol.'), ctrl("over"))
        os._exit(1)
    elif mode == "aborted":
        send(ctrl("understood"), ctrl("aborted", "Traceback (most recent call last):\nValueError: kaput"),
             ctrl("over"))
        os._exit(1)
    elif mode == "missing-understood":
        send(commands(0.1, 0.1), ctrl("over"))
    elif mode == "no-commands":
        send(ctrl("understood"), ctrl("over"))
    elif mode == "two-commands":
        send(ctrl("understood"), commands(0.1, 0.1), commands(0.2, 0.2), ctrl("over"))
    elif mode in ("nan", "range", "wrong-type", "bool"):
        value = {"nan": math.nan, "range": 1.5, "wrong-type": "fast", "bool": True}[mode]
        send(ctrl("understood"), commands(value, 0.0), ctrl("over"))
    elif mode == "incompatible":
        send(ctrl("understood"), topic("protocol_description", {"data": {"inputs": {}, "outputs": {}}}),
             ctrl("over"))
    elif mode == "stdout-flood":
        OUT.write(b"\x5b" + (1 << 40).to_bytes(8, "big"))  # a byte string of 1 TB: never ends
        while True:
            OUT.write(b"\0" * 65536)
    elif mode == "stdout-flood-messages":
        skipped = cbor2.dumps({"compat": ["z9"], "topic": "noise", "data": None, "timing": None})
        while True:
            OUT.write(skipped * 1000)
    elif mode == "stderr-flood":
        while True:
            sys.stderr.write("x" * 8191 + "\n")
    elif mode == "spawn-and-hang":
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(1000)"])
        print(f"spawned {child.pid}", file=sys.stderr, flush=True)
    OUT.flush()
    hang()


def answer(msg):
    if "control" in msg:
        if msg["control"] == "capabilities":
            send(ctrl("understood"), ctrl("capabilities", {"z2": {"protocol-reflection": True}}), ctrl("over"))
        return
    outputs = []
    if msg["topic"] == "wrapper.describe_protocol":
        outputs = [topic("protocol_description", DESCRIPTION)]
    elif msg["topic"] == "get_commands":
        outputs = [commands(0.25, -0.25)]
    send(ctrl("understood"), *outputs, ctrl("over"))


def main():
    global IN, OUT
    IN, OUT = _streams()
    mode = sys.argv[1]
    trigger = sys.argv[2] if len(sys.argv) > 2 else "get_commands"
    decoder = cbor2.CBORDecoder(IN)
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return
        if msg.get("control", msg.get("topic")) == trigger:
            misbehave(mode)
        answer(msg)


if __name__ == "__main__":
    main()
