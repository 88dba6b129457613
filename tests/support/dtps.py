"""What the DTPS tests share: the ``sdk`` mark, and a fake DTPS robot (tests/dtps_robots/fake_robot.py) to drive.

Tests marked ``sdk`` need the SDK environment (``proxybench dtps setup``) and skip with the reason when it is
missing, except under ``PROXYBENCH_REQUIRE_DTPS=1`` (CI sets it after running setup), where they fail.
"""

from __future__ import annotations

import json
import os
import queue
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

from proxybench.dtps.env import DtpsEnvError, sdk_python

FAKE_ROBOT = Path(__file__).parent.parent / "dtps_robots" / "fake_robot.py"


def _sdk_missing() -> str | None:
    try:
        sdk_python()
    except DtpsEnvError as exc:
        return str(exc)
    return None


SDK_MISSING = _sdk_missing()
if SDK_MISSING and os.environ.get("PROXYBENCH_REQUIRE_DTPS") == "1":
    raise RuntimeError(f"PROXYBENCH_REQUIRE_DTPS=1 but {SDK_MISSING}")
sdk = pytest.mark.skipif(SDK_MISSING is not None, reason=f"{SDK_MISSING}")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def road_jpeg(pose: tuple[float, float, float], size: tuple[int, int] = (160, 120)) -> bytes:
    """What proxybench's camera sees at ``pose`` on loop_3x3, as JPEG (the fake robot's fixed camera frame)."""
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.protocol import jpeg

    sim = Simulator("loop_3x3", DomainParams(image_width=size[0], image_height=size[1]))
    sim.reset(0, 0, pose)
    return jpeg.encode(sim.render()[0])


class FakeRobot:
    """The fake DTPS robot at ``127.0.0.1:<free port>/fakebot``, standing at ``start`` (where ``state/reset`` puts
    it back); ``blackout_after``/``blackout_for``: its network drops that long after it first moved. Every wait
    is bounded; the process is killed on exit."""

    def __init__(self, tmp_path: Path, start: tuple[float, float, float], *, blackout_after: float | None = None,
                 blackout_for: float = 2.0, start_timeout: float = 90.0):
        self.port, internal = free_port(), free_port()
        self.address = f"127.0.0.1:{self.port}/fakebot"
        self.log = tmp_path / f"fakebot-{self.port}.jsonl"
        self.log.touch()
        image = tmp_path / "fakebot.jpg"
        image.write_bytes(road_jpeg(start))
        argv = [str(sdk_python()), str(FAKE_ROBOT), "--port", str(self.port), "--internal-port", str(internal),
                "--jpeg", str(image), "--log", str(self.log), "--start", *(repr(float(v)) for v in start)]
        if blackout_after is not None:
            argv += ["--blackout-after", str(blackout_after), "--blackout-for", str(blackout_for)]
        self.stderr = (tmp_path / f"fakebot-{self.port}.stderr").open("w")
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                     text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        try:
            self.wait_line("serving 1", start_timeout)
        except BaseException:
            self.close()
            raise

    def _read(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            self.lines.put(line.strip())

    def wait_line(self, text: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                if self.lines.get(timeout=max(0.0, deadline - time.monotonic())) == text:
                    return
            except queue.Empty:
                raise AssertionError(f"the fake robot did not say {text!r} within {timeout:g} s (exit code "
                                     f"{self.proc.poll()})") from None

    def place(self, x: float, y: float, theta: float) -> None:
        """Put it at (x, y, θ), as an operator's hands do."""
        self.proc.stdin.write(f"place {x!r} {y!r} {theta!r}\n")  # type: ignore[union-attr]
        self.proc.stdin.flush()  # type: ignore[union-attr]
        self.wait_line("placed", 30.0)

    def commands(self) -> list[dict]:
        """Every wheel command it received: wall, left, right, incarnation (its network's, after a blackout)."""
        return [json.loads(line) for line in self.log.read_text().splitlines() if line.strip()]

    def wait_for_command(self, pred, timeout: float) -> dict | None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [c for c in self.commands() if pred(c)]
            if found:
                return found[-1]
            time.sleep(0.1)
        return None

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait(timeout=30)
        self.stderr.close()

    def __enter__(self) -> FakeRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
