"""Threads of the compiled kernels: one thread or all gives the same frames, the choice follows the
timings, and a forked child never enters the threading layer."""

from __future__ import annotations

import os

import numpy as np
import pytest

from proxybench.domain import parallelism
from proxybench.domain.lane_pose import LP
from proxybench.domain.maps import MapObject, load_map
from proxybench.domain.npcs import NpcRobot, Traffic
from proxybench.domain.parallelism import ThreadChoice, force_parallel, threads_available
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator


@pytest.fixture
def forced():
    yield force_parallel
    force_parallel(None)


def frames(mode: bool, params: DomainParams, n: int, steps: int = 4) -> np.ndarray:
    """Frames of ``steps`` steps of a batch with map objects and NPC robots, all on one thread or on all."""
    force_parallel(mode)
    m = load_map("loop_3x3")
    m = m.__class__(**{**m.__dict__, "objects": (MapObject("duckie", 0.65, 0.88), MapObject("cone", 1.1, 0.88))})
    sim = Simulator(m, params, n=n, npcs=Traffic(robots=(NpcRobot(ahead=0.6),)))
    for i in range(n):
        sim.reset(i, seed=7 + i)
    out = []
    for _ in range(steps):
        out.append(sim.render().copy())
        sim.step(np.column_stack([0.3 - sim.lane[:, LP.LATERAL], 0.3 + sim.lane[:, LP.LATERAL]]))
    return np.stack(out)


@pytest.mark.parametrize(("size", "n", "blur"), [((640, 480), 1, 0.0), ((160, 120), 8, 0.05)])
def test_parallel_frames_equal_serial_frames(forced, size, n, blur):
    p = DomainParams(image_width=size[0], image_height=size[1], blur_time=blur, noise_std=3.0, vignetting=0.2)
    np.testing.assert_array_equal(frames(True, p, n), frames(False, p, n))


def fed(choice: ThreadChoice, serial: float, parallel: float, calls: int) -> list[bool]:
    """Drive ``choice`` for ``calls`` calls whose wall time per unit is ``serial`` / ``parallel``."""
    modes = []
    for _ in range(calls):
        mode = choice.parallel(10**6)
        choice.record(mode, (parallel if mode else serial) * 10**6, 10**6)
        modes.append(mode)
    return modes


class Ticks:
    """A clock that advances one second per reading."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        self.t += 1.0
        return self.t


def test_choice_keeps_the_faster_mode_and_follows_the_load(monkeypatch):
    monkeypatch.setattr(parallelism, "threads_available", lambda: 2)
    choice = ThreadChoice(probe_every=10.0, max_interval=10.0, clock=Ticks())
    modes = fed(choice, serial=1.0, parallel=0.5, calls=40)
    assert modes[:2] == [False, False]  # one thread is timed first
    assert all(modes[2:5])  # then all threads are tried, and win
    assert choice.current and modes[-10:].count(True) >= 7
    modes = fed(choice, serial=1.0, parallel=4.0, calls=40)  # a neighbour takes the other core
    assert not choice.current
    assert modes[-20:].count(True) <= 6  # only the periodic tries
    fed(choice, serial=1.0, parallel=0.5, calls=40)  # the neighbour has gone
    assert choice.current


def test_choice_backs_off_while_parallel_loses(monkeypatch):  # the doubling alone (no lost-time budget)
    monkeypatch.setattr(parallelism, "threads_available", lambda: 2)
    choice = ThreadChoice(probe_every=2.0, max_interval=1000.0, try_budget=float("inf"), clock=Ticks())
    modes = fed(choice, serial=1.0, parallel=3.0, calls=300)
    assert not choice.current
    assert 3 <= modes.count(True) <= 30  # the first try, then tries ever further apart
    assert "PP" not in "".join("P" if m else "s" for m in modes)  # a try that loses at once stops at once
    assert choice._interval >= 64.0


class WallClock:
    """A clock that the calls themselves advance by their (simulated) wall time."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_lost_tries_cost_at_most_their_budget(monkeypatch):
    """Beside a busy neighbour a parallel call cost 4–7 serial ones (measured): the tries that show it may
    take only ``try_budget`` of the time, however short the interval would otherwise be."""
    monkeypatch.setattr(parallelism, "threads_available", lambda: 2)
    clock = WallClock()
    choice = ThreadChoice(probe_every=0.5, max_interval=30.0, try_budget=0.01, clock=clock)
    serial, parallel, lost = 0.011, 0.060, 0.0
    while clock.t < 20.0:  # 20 s of steps at 11 ms
        mode = choice.parallel(10**6)
        took = parallel if mode else serial
        choice.record(mode, took, 10**6)
        clock.t += took
        lost += (took - serial) if mode else 0.0
    assert not choice.current
    first_try = parallel - serial  # the one try every process pays before it knows
    assert lost <= first_try + 0.01 * clock.t + parallel  # within the budget (and one call's rounding)
    assert choice._interval >= (parallel - serial) / 0.01


def test_small_work_and_one_thread_stay_serial(monkeypatch, forced):
    choice = ThreadChoice()
    assert not choice.parallel(choice.min_work - 1)
    monkeypatch.setattr(parallelism, "threads_available", lambda: 1)
    forced(True)
    assert not choice.parallel(10**9)


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs fork")
def test_forked_child_uses_one_thread():
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: report and leave without running pytest's teardown
        os.write(w, str(threads_available()).encode())
        os._exit(0)
    os.close(w)
    assert os.read(r, 16) == b"1"
    os.waitpid(pid, 0)


def test_renders_from_two_python_threads_equal_serial(forced):
    """Two threads rendering at once (one gets the threads, the other runs serial) draw the right frames."""
    from concurrent.futures import ThreadPoolExecutor

    p = DomainParams(image_width=320, image_height=240, blur_time=0.0)
    serial = frames(False, p, 1, steps=3)
    forced(True)
    with ThreadPoolExecutor(2) as pool:
        results = list(pool.map(lambda _: frames(True, p, 1, steps=3), range(4)))
    for r in results:
        np.testing.assert_array_equal(r, serial)
