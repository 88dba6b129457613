"""A stand-in for a real AIDO agent node as users start it (cbor2 only, so it starts fast).

Like the zuper-nodes wrapper on Python >= 3.11 it crashes on ``wrapper.describe_protocol`` (understood,
aborted with a traceback, over, exit 1) although its data path works; like many user nodes it prints to
stdout (``--print``), needs its working directory (``--need FILE``: a file it reads relative to it), and
may take long to start (``--slow S``). Each start appends a line to ``starts.log`` in its working
directory (or ``--starts-log``); ``--pid-file F`` writes its pid there (to check that it was killed).
Streams: stdin/stdout or ``AIDONODE_DATA_IN`` / ``AIDONODE_DATA_OUT`` (``fifo:`` creates the FIFO unless it
exists), as zuper nodes do.
"""

import argparse
import os
import sys
import time

import cbor2


def streams():
    path_in, path_out = os.environ.get("AIDONODE_DATA_IN"), os.environ.get("AIDONODE_DATA_OUT")
    fin = open(path_in, "rb", buffering=0) if path_in else sys.stdin.buffer  # noqa: SIM115 - kept open
    if path_out and path_out.startswith("fifo:"):
        path_out = path_out[5:]
        if not os.path.exists(path_out):  # as zuper-nodes: a FIFO made by the caller is used as it is
            os.mkfifo(path_out)
    return fin, (open(path_out, "wb") if path_out else sys.stdout.buffer)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--print", action="store_true", help="print to stdout at start and at each episode")
    p.add_argument("--need", help="a file that must exist in the working directory")
    p.add_argument("--slow", type=float, default=0.0, help="seconds to sleep before starting")
    p.add_argument("--hang-on", default=None, help="hang at this input topic")
    p.add_argument("--pid-file", default=None)
    p.add_argument("--starts-log", default="starts.log", help="where to log starts (a read-only package: /scratch)")
    args = p.parse_args()
    with open(args.starts_log, "a") as f:
        f.write(f"{os.getpid()}\n")
    if args.pid_file:
        with open(args.pid_file, "w") as f:
            f.write(str(os.getpid()))
    if args.need and not os.path.exists(args.need):
        print(f"cannot find {args.need!r} in {os.getcwd()}", file=sys.stderr, flush=True)
        return 2
    time.sleep(args.slow)
    if args.print:
        print("solution: loading the model... done", flush=True)
    fin, fout = streams()

    def send(*msgs):
        fout.write(b"".join(cbor2.dumps(m) for m in msgs))
        fout.flush()

    def ctrl(code, data=None):
        return {"control": code, "data": data}

    decoder = cbor2.CBORDecoder(fin)
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return 0
        if "control" in msg:
            send(ctrl("understood"), ctrl("capabilities", {"z2": {"protocol-reflection": True}}), ctrl("over"))
            continue
        topic = msg["topic"]
        if topic == args.hang_on:
            time.sleep(1000)
        if topic == "wrapper.describe_protocol":  # what zuper-nodes 6.2.17 does on Python 3.11
            trace = ('Exception while handling a message on topic "describe_protocol".\n\n'
                     "| zuper_commons.types.exceptions.ZValueError: Cannot interpret the type @T\n| │ T: typing.Any\n")
            send(ctrl("understood"), ctrl("aborted", trace), ctrl("over"))
            print("Exception: Error in node Agent", file=sys.stderr, flush=True)
            return 1
        out = []
        if topic == "episode_start" and args.print:
            print("solution: new episode", flush=True)
        if topic == "get_commands":
            out = [{"compat": ["z2"], "topic": "commands", "timing": None,
                    "data": {"wheels": {"motor_left": 0.2, "motor_right": 0.25}}}]
        send(ctrl("understood"), *out, ctrl("over"))


if __name__ == "__main__":
    sys.exit(main())
