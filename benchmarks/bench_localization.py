"""Localisation accuracy against the simulator's truth, and throughput, on the Autolab maps (issue 27).

    .venv/bin/python benchmarks/bench_localization.py            # 3 Autolab maps × 30 s (long: rendering dominates)
    .venv/bin/python benchmarks/bench_localization.py --quick    # one map, 8 s
    .venv/bin/python benchmarks/bench_localization.py --log D    # an existing `run --watchtowers` log only
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_localization.py --keep-up [--log D]   # CPU per simulated s
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_localization.py --online [--log D]    # online: CPU and lag

``--keep-up`` (issue 36 item 4): the technical track's 30-s run (or ``--log D``, ``--map``) localised in this
process pinned to one core, as the Autolab evaluator localises an episode (one detection process), twice side by
side: detecting every frame, and re-using a watchtower's last detection while its view is unchanged (the default).
It prints CPU seconds (this process's, threads included; imports before the clock) per simulated second, where they
went (decoding and detecting, measuring and solving), and the median / p95 position error against the truth.

``--online`` (issue 36 item 4, online): the same run replayed in real time (each frame offered at its episode time,
as the watchtower reader receives it: its bytes) to the Autolab evaluator's online detection
(``autolab.online.OnlineDetector``: a bounded queue, one worker thread) in this process pinned to one core, twice
side by side: quiet, and with a busy neighbour (a process multiplying numpy matrices in a loop, pinned to the same
core). It prints CPU per simulated second (this process's during the replay, plus the pose graph at the end), the
lag (frames queued when a frame arrived: median, p95, most), frames dropped, the wall time from the episode's last
frame until its detections were done, the solve at the end, and the position error against the truth.

Per map: the PID agent drives one episode while the map's generated watchtower layout (``--watchtowers auto``)
records; the log is localised (pupil-apriltags, decimation 2, two detection processes) and each localised sample
is compared with the true pose at its time. Columns: median and 95th percentile of the position error [cm] and
heading error [deg], over the samples at which at least two watchtowers saw the robot ("≥2 views") and over all;
the share of the episode localised (of 0.1 s slots, those with a sample within one watchtower frame); the
median 1σ the pose graph gives for x and y [cm]; throughput, watchtower frames per second through detection
on 2 processes (the machine's 2 cores). The second table solves the same detections with GTSAM and with SciPy.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

MAPS = ("ETHZ_autolab_technical_track", "ETHZ_autolab_fast_track", "ETU_autolab_track")


def record(map_name: str, seconds: float, out: Path) -> Path:
    """One PID episode with the map's auto watchtowers, as ``proxybench run --watchtowers auto`` records it."""
    from proxybench.agents import make_agent
    from proxybench.autolab.cli_support import finish_sim_log, layout_streams
    from proxybench.domain.maps import load_map
    from proxybench.domain.params import DomainParams
    from proxybench.runner.jobs import DomainSpec
    from proxybench.runner.record import record_run

    layout, streams, _ = layout_streams("auto", load_map(map_name))
    domain = DomainSpec("simulation", DomainParams(image_width=32, image_height=24))
    traj = record_run(domain, make_agent("pid"), map_name, 0, seconds, out, video=False, meta={"map": map_name},
                      streams=streams).trajectory
    traj.save(out / "trajectory.parquet")
    finish_sim_log(out, layout, map_name, "pid", 0, seconds, traj.termination)
    return out


def errors(track, truth: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Position [cm] and heading [deg] error of each localised sample against the truth at its time."""
    x = np.interp(track.t, truth["t"], truth["x"])
    y = np.interp(track.t, truth["t"], truth["y"])
    th = np.interp(track.t, truth["t"], np.unwrap(truth["theta"]))
    pos = 100 * np.hypot(track.pose[:, 0] - x, track.pose[:, 1] - y)
    head = np.degrees(np.abs(np.remainder(track.pose[:, 2] - th + math.pi, 2 * math.pi) - math.pi))
    return pos, head


def share_localised(track, truth: dict[str, np.ndarray], window: float) -> float:
    slots = np.arange(0.0, float(truth["t"][-1]), 0.1)
    if not track.t.size:
        return 0.0
    k = np.clip(np.searchsorted(track.t, slots), 1, track.t.size - 1)
    near = np.minimum(np.abs(track.t[k] - slots), np.abs(track.t[k - 1] - slots))
    return float(np.mean(near <= window))


def measure(log_dir: Path, map_name: str) -> dict:
    from proxybench.autolab.localize import detect_log, localize_log
    from proxybench.autolab.logs import read_log
    from proxybench.domain.maps import load_map
    from proxybench.tasks.trajectory import Trajectory

    log = read_log(log_dir)
    m = load_map(map_name)
    t0 = time.perf_counter()
    frames = detect_log(log, "apriltag", workers=2, decimate=2.0)
    detect_s = time.perf_counter() - t0
    truth = Trajectory.load(log.truth).columns
    row = {"map": map_name, "towers": len(log.streams), "frames": len(frames), "fps": len(frames) / detect_s}
    rate = min(len(s.frames) / max(s.frames[-1].t - s.frames[0].t, 1e-9) for s in log.streams)
    for solver in ("gtsam", "scipy"):
        t1 = time.perf_counter()
        loc = localize_log(log, m, frames=frames, solver=solver)
        track = loc.robots.get("ego")
        pos, head = errors(track, truth)
        two = track.views >= 2
        row[solver] = {"solve_s": time.perf_counter() - t1, "pos": pos, "head": head, "two": two,
                       "share": share_localised(track, truth, 1.0 / rate),
                       "sigma": 100 * float(np.nanmedian(track.sigma[:, :2])) if solver == "gtsam" else float("nan")}
    return row


def keep_up(log_dir: Path, map_name: str) -> list[dict]:
    """Localise one log on one core, detecting every frame and re-using unchanged views: CPU, its split, error."""
    import os

    import cv2
    import gtsam  # noqa: F401 - imported before the clock, as in a running evaluator
    import pupil_apriltags  # noqa: F401

    from proxybench.autolab.localize import localize_log
    from proxybench.autolab.logs import read_log
    from proxybench.domain.maps import load_map
    from proxybench.tasks.trajectory import Trajectory

    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)
    log, m = read_log(log_dir), load_map(map_name)
    truth = Trajectory.load(log.truth).columns
    seconds = float(log.manifest.seconds or truth["t"][-1])
    rows = []
    for reuse in (False, True):
        c0 = time.process_time()
        loc = localize_log(log, m, workers=1, decimate=2.0, reuse=reuse)
        cpu = time.process_time() - c0
        track = loc.robots["ego"]
        pos, _ = errors(track, truth)
        rows.append({"reuse": reuse, "frames": loc.frames, "seconds": seconds, "cpu": cpu, "samples": pos.size,
                     "detect": loc.timing["detect_cpu_s"], "solve": loc.timing["solve_cpu_s"], "pos": pos,
                     "detected": loc.detected})
    return rows


#: the busy neighbour of ``--online``: a process that multiplies matrices without end
HOG = ("import numpy as np\n"
       "a = np.random.default_rng(0).random((300, 300))\n"
       "while True:\n"
       "    a = a @ a\n"
       "    a /= np.abs(a).max()\n")


def _neighbour(core: int):
    """The busy neighbour, started and pinned to ``core`` (its caller stops it)."""
    import os
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", HOG], env={**os.environ, "OMP_NUM_THREADS": "1",
                                                              "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    os.sched_setaffinity(proc.pid, {core})
    return proc


def replay(log, online, speed: float) -> tuple[object, list[int], float]:
    """Offer ``log``'s frames (their bytes) to ``online`` at their episode times (``speed`` × real time), as the
    watchtower reader would; (the episode, frames queued at each offer, wall seconds from the last frame to done)."""
    from pathlib import Path as _P

    ep = online.begin(log.root / "watchtowers")
    order = sorted((fr.t, s.name, int(_P(fr.ref).stem), fr.ref) for s in log.streams for fr in s.frames)
    t0, start, queued = order[0][0], time.perf_counter(), []
    for t, name, index, ref in order:
        delay = start + (t - t0) / speed - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        queued.append(online.lag().queued)
        ep.frame(name, index, _P(ref).read_bytes(), t)
    ep.end()
    last = time.perf_counter()
    ep.wait()
    return ep, queued, time.perf_counter() - last


def online_rows(log_dir: Path, map_name: str, speed: float, max_queue: int) -> list[dict]:
    """Replay one log to the online detection on one core, quiet and beside a busy neighbour (see the module)."""
    import os

    import cv2
    import gtsam  # noqa: F401 - imported before the clock, as in a running evaluator
    import pupil_apriltags  # noqa: F401

    from proxybench.autolab.localize import localize_log
    from proxybench.autolab.logs import read_log
    from proxybench.autolab.online import OnlineDetector
    from proxybench.domain.maps import load_map
    from proxybench.tasks.trajectory import Trajectory

    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    cv2.setNumThreads(1)
    log, m = read_log(log_dir), load_map(map_name)
    truth = Trajectory.load(log.truth).columns
    seconds = float(log.manifest.seconds or truth["t"][-1])
    rows = []
    for busy in (False, True):
        hog = _neighbour(core) if busy else None
        try:
            online = OnlineDetector(decimate=2.0, max_queue=max_queue)
            c0 = time.process_time()
            ep, queued, drain = replay(log, online, speed)
            online.close()
            c1 = time.process_time()
            loc = localize_log(log, m, frames=ep.frames_for(log))
            c2 = time.process_time()
        finally:
            if hog is not None:
                hog.kill()
                hog.wait()
        pos, _ = errors(loc.robots["ego"], truth)
        rep = ep.report()
        rows.append({"busy": busy, "seconds": seconds, "frames": rep["frames"], "detected": rep["detected"],
                     "dropped": sum(rep["dropped"].values()), "cpu": c1 - c0, "worker": rep["cpu_s"],
                     "solve": c2 - c1, "queued": np.array(queued), "drain": drain, "pos": pos})
    return rows


def show_online(args: argparse.Namespace) -> None:
    """Record (unless ``--log``) and print the online table."""
    import os

    name = args.map or MAPS[0]
    with tempfile.TemporaryDirectory() as tmp:
        log = args.log if args.log is not None else record(name, args.seconds or 30.0, Path(tmp) / name)
        rows = online_rows(log, name, args.speed, args.max_queue)
    load = os.getloadavg()[0]
    r0 = rows[0]
    table = Table(title=f"Online localisation on one core: {name}, {r0['seconds']:g} s, {r0['frames']} frames "
                        f"replayed at {args.speed:g}× real time, queue ≤ {args.max_queue} (load average {load:.1f})")
    for col in ("neighbour", "frames detected", "dropped", "CPU during the episode [s] (worker's)",
                "solve at the end [s]", "CPU per simulated s", "queued: median / p95 / most",
                "done after the last frame [s]", "pos. err. median / p95 [cm]"):
        table.add_column(col, justify="left" if col == "neighbour" else "right")
    for r in rows:
        q = r["queued"]
        table.add_row("busy (numpy matmul, same core)" if r["busy"] else "quiet", str(r["detected"]),
                      str(r["dropped"]), f"{r['cpu']:.1f} ({r['worker']:.1f})", f"{r['solve']:.2f}",
                      f"{(r['cpu'] + r['solve']) / r['seconds']:.2f}",
                      f"{np.median(q):.0f} / {np.percentile(q, 95):.0f} / {q.max()}", f"{r['drain']:.2f}",
                      f"{_q(r['pos'], 50)} / {_q(r['pos'], 95)}")
    Console(width=200).print(table)


def _q(v: np.ndarray, q: float) -> str:
    return f"{np.percentile(v, q):.2f}" if v.size else "–"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one map, 8 s")
    ap.add_argument("--seconds", type=float, default=None, help="episode length (default 30, --quick 8)")
    ap.add_argument("--log", type=Path, default=None, help="measure this log (its map: --map) instead of recording")
    ap.add_argument("--map", default=None, help="the map of --log, or the one map to record")
    ap.add_argument("--keep-up", action="store_true", help="CPU per simulated second on one core (the technical "
                    "track, 30 s), every frame detected against unchanged views re-used")
    ap.add_argument("--online", action="store_true", help="online detection on one core, quiet and beside a busy "
                    "neighbour: CPU per simulated second and lag (the technical track, 30 s)")
    ap.add_argument("--speed", type=float, default=1.0, help="--online: replay at this many times real time")
    ap.add_argument("--max-queue", type=int, default=None, help="--online: the queue's bound (default: the "
                    "evaluator's, autolab.online.MAX_QUEUE)")
    args = ap.parse_args()
    if args.keep_up:
        return show_keep_up(args)
    if args.online:
        if args.max_queue is None:
            from proxybench.autolab.online import MAX_QUEUE

            args.max_queue = MAX_QUEUE
        return show_online(args)
    seconds = args.seconds or (8.0 if args.quick else 30.0)
    maps = [args.map] if args.map else (MAPS[:1] if args.quick else MAPS)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in maps:
            log = args.log if args.log is not None else record(name, seconds, Path(tmp) / name)
            rows.append(measure(log, name))
    console = Console(width=200)
    acc = Table(title=f"Localisation vs the simulator's truth (PID, {seconds:g} s; pupil-apriltags, GTSAM; 2 cores)")
    for col in ("map", "towers", "samples (≥2 views)", "pos. err. median / p95 [cm], ≥2 views",
                "heading err. median / p95 [deg], ≥2 views", "pos. err. median / p95 [cm], all", "share localised",
                "σ_xy median [cm]", "frames/s"):
        acc.add_column(col, justify="left" if col == "map" else "right")
    for r in rows:
        g = r["gtsam"]
        two = g["two"]
        acc.add_row(r["map"], str(r["towers"]), f"{g['pos'].size} ({two.sum()})",
                    f"{_q(g['pos'][two], 50)} / {_q(g['pos'][two], 95)}",
                    f"{_q(g['head'][two], 50)} / {_q(g['head'][two], 95)}",
                    f"{_q(g['pos'], 50)} / {_q(g['pos'], 95)}", f"{100 * g['share']:.0f} %", f"{g['sigma']:.2f}",
                    f"{r['fps']:.1f}")
    console.print(acc)
    solv = Table(title="The same detections through both solvers")
    for col in ("map", "solver", "pos. err. median / p95 [cm]", "heading err. median [deg]", "solve [s]"):
        solv.add_column(col, justify="left" if col in ("map", "solver") else "right")
    for r in rows:
        for s in ("gtsam", "scipy"):
            g = r[s]
            solv.add_row(r["map"], s, f"{_q(g['pos'], 50)} / {_q(g['pos'], 95)}", _q(g["head"], 50),
                         f"{g['solve_s']:.2f}")
    console.print(solv)


def show_keep_up(args: argparse.Namespace) -> None:
    """Record (unless ``--log``) and print the keep-up table."""
    name = args.map or MAPS[0]
    with tempfile.TemporaryDirectory() as tmp:
        log = args.log if args.log is not None else record(name, args.seconds or 30.0, Path(tmp) / name)
        rows = keep_up(log, name)
    import os

    load = os.getloadavg()[0]
    table = Table(title=f"Localisation on one core: {name}, {rows[0]['seconds']:g} s, {rows[0]['frames']} frames "
                        f"(load average {load:.1f})")
    for col in ("detection", "frames detected", "CPU [s]", "CPU per simulated s", "decode + detect [s]",
                "measure + solve [s]", "samples", "pos. err. median / p95 [cm]"):
        table.add_column(col, justify="left" if col == "detection" else "right")
    for r in rows:
        table.add_row("unchanged views re-used" if r["reuse"] else "every frame", str(r["detected"]),
                      f"{r['cpu']:.1f}",
                      f"{r['cpu'] / r['seconds']:.2f}", f"{r['detect']:.1f}", f"{r['solve']:.1f}", str(r["samples"]),
                      f"{_q(r['pos'], 50)} / {_q(r['pos'], 95)}")
    Console(width=200).print(table)


if __name__ == "__main__":
    main()
