"""Repeatability studies (thesis §5.4): do runs of one agent agree, on one robot, across robots, across labs?

A *design* is labs × robots per lab × runs per robot. The thesis' three (figs. 5.8–5.10):

| design | labs × robots × runs | what differs between runs |
| --- | --- | --- |
| ``repeatability`` | 1 × 1 × 9 | only the run: latency jitter, sensor noise, the operator's placement |
| ``inter-robot`` | 1 × 3 × 3 | also the robot: trim, gain, camera mounting |
| ``inter-lab`` | 2 × 1 × 6 | also the lab (light, road paint, floor texture) and its own robot |

Every run starts from the same nominal pose; the operator's placement error (``placement``, default
0.5 cm across the lane and 1° of heading, standard deviations) is drawn per run. MPD / MOD are the
thesis' signed means (``tasks.metrics.repeatability``), with the run-to-run spread and, where a design
has several robots or labs, the split into within- and between-group variability.

Targets, all three kinds (and every result says which):

- :func:`repeatability_study`: the reality model, a *simulated* stand-in for real Duckiebots. A robot is
  ``hardware_variation`` drawn from (seed, lab, robot), so robot 0 of lab 0 is the same robot in every
  design; a lab other than lab 0 is :func:`lab_variation` drawn from (seed, lab). Every run is a runner job
  (cached and resumable, like every episode).
- :func:`recorded_study`: trajectories recorded in real labs, ``LAB/ROBOT/run.csv`` (or Parquet).
- :func:`robot_study`: robot nodes on the robot protocol, one command per robot.

:class:`RepeatabilityConfig` (:mod:`.repeatability_config`) holds a study's settings (``proxybench
repeatability``'s options are generated from it) and :func:`run_repeatability` runs the study it names.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams
from proxybench.domain.reality import hardware_variation, reality_params
from proxybench.experiments.repeatability.config import DESIGNS, Design, RepeatabilityConfig
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DEFAULT_FRAME_RATE, AgentSpec, DomainSpec, Job
from proxybench.runner.starts import start_pose
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.metrics import repeatability
from proxybench.tasks.trajectory import Termination, Trajectory

if TYPE_CHECKING:
    from proxybench.protocol.options import RobotNodeOptions

__all__ = ["DESIGNS", "THESIS_FIGURES", "Design", "DesignResult", "RepeatabilityConfig", "RepeatabilityResult",
           "design_figures", "lab_variation", "recorded_study", "repeatability_study", "robot_study",
           "run_repeatability"]


#: thesis §5.4 (real Duckiebots in the ETHZ and TTIC Autolabs): AVG / STD of MPD [cm] and MOD [deg]
THESIS_FIGURES: dict[str, dict[str, float]] = {
    "repeatability": {"MPD_cm": -6.2, "MPD_std_cm": 1.3, "MOD_deg": -0.8, "MOD_std_deg": 2.8},
    "inter-robot": {"MPD_cm": 1.1, "MPD_std_cm": 3.4, "MOD_deg": -0.4, "MOD_std_deg": 5.2},
    "inter-lab": {"MPD_cm": 2.2, "MPD_std_cm": 2.5, "MOD_deg": -0.4, "MOD_std_deg": 3.9},
}


@dataclass
class DesignResult:
    """The runs of one design, each run's lab / robot label, and the MPD / MOD figures."""

    design: Design
    runs: list[Trajectory]
    labels: list[str]
    figures: dict[str, float]

    @property
    def early(self) -> int:
        """Runs that ended before their time (left the road, collided, failed)."""
        return sum(t.termination is not Termination.TIMEOUT for t in self.runs)


@dataclass
class RepeatabilityResult:
    """Per design: the runs and their figures; ``source`` says what the target was."""

    designs: dict[str, DesignResult]
    source: str
    notes: dict[str, str] = field(default_factory=dict)
    config: RepeatabilityConfig | None = None  # the study's settings (its report names the agent and length)

    @property
    def runs(self) -> dict[str, list[Trajectory]]:
        return {k: v.runs for k, v in self.designs.items()}

    @property
    def figures(self) -> dict[str, dict[str, float]]:
        return {k: v.figures for k, v in self.designs.items()}


def lab_variation(rng: np.random.Generator, base: DomainParams) -> DomainParams:
    """Another lab: its own lights, road paint and floor texture."""
    light = tuple(float(v) for v in np.clip(rng.normal(1.0, 0.08, 3), 0.7, 1.3))
    road = tuple(float(v) for v in np.clip(np.asarray(base.road_rgb) + rng.normal(0.0, 8.0), 20, 120))
    return base.replace(light_rgb=light, road_rgb=road, brightness=float(rng.normal(0.0, 6.0)),
                        texture_seed=int(rng.integers(0, 2**31)), texture_noise=float(rng.uniform(0.05, 0.2)))


def _rng(*key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(list(key)))


def robot_params(base: DomainParams, seed: int, lab: int, robot: int) -> DomainParams:
    """Lab ``lab``'s robot ``robot``: the lab's conditions (lab 0: ``base`` as is) and the robot's hardware."""
    lab_params = base if lab == 0 else lab_variation(_rng(seed, 0x1AB, lab), base)
    return hardware_variation(_rng(seed, 0xB07, lab, robot), lab_params)


def placed(start: tuple[float, float, float], rng: np.random.Generator,
           placement: tuple[float, float]) -> tuple[float, float, float]:
    """The nominal start moved by the operator's placement error (σ across the lane [m], σ heading [deg])."""
    x, y, th = start
    d, a = rng.normal(0.0, placement[0]), np.radians(rng.normal(0.0, placement[1]))
    return float(x - np.sin(th) * d), float(y + np.cos(th) * d), float(th + a)


def repeatability_study(
    agent: str, designs: Mapping[str, Design] | None = None, seconds: float = 30.0, map_name: str = "loop_3x3",
    seed: int = 0, image_size: tuple[int, int] = (160, 120), placement: tuple[float, float] = (0.005, 1.0),
    progress: Callable[[str, int, int], None] | None = None, run_dir: str | Path | None = None,
    backend: Backend | None = None,
) -> RepeatabilityResult:
    """Run ``agent`` in each design on the reality model (simulated); every run from the same nominal start.

    Each run is a runner job (a reality-model domain with that robot's θ), cached in ``run_dir`` (None: a
    temporary folder), so an interrupted study resumes.
    """
    designs = dict(DESIGNS if designs is None else designs)
    if seconds <= 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    w, h = image_size
    base = reality_params(image_width=w, image_height=h)
    start = start_pose(map_name, seed, base)
    out: dict[str, DesignResult] = {}
    with _folder(run_dir) as folder:
        for k, (name, d) in enumerate(designs.items()):
            cells = [(lab, r, i) for lab in range(d.labs) for r in range(d.robots) for i in range(d.runs)]
            jobs = [Job(AgentSpec(agent), DomainSpec(f"lab {lab}/robot {r}",
                                                     robot_params(base, seed, lab, r),
                                                     DomainKind.REALITY_MODEL),
                        map_name, j, int(np.random.SeedSequence([seed, k, lab, r, i]).generate_state(1)[0] % 2**31),
                        seconds, pose=placed(start, _rng(seed, 0x9A5E, k, j), placement))
                    for j, (lab, r, i) in enumerate(cells)]
            labels = [f"lab {lab}/robot {r}" for lab, r, _ in cells]
            trajs = _trajectories(jobs, folder, backend, name, progress)
            for tr, (lab, r, i) in zip(trajs, cells, strict=True):
                tr.meta.update({"design": name, "lab": lab, "robot": r, "run": i})
            out[name] = DesignResult(d, trajs, labels, design_figures(trajs, labels, d))
    return RepeatabilityResult(out, "reality-model (simulated stand-in for real Duckiebots)")


@contextmanager
def _folder(run_dir: str | Path | None) -> Iterator[Path]:
    if run_dir is not None:
        yield Path(run_dir)
        return
    with tempfile.TemporaryDirectory(prefix="proxybench-repeatability-") as tmp:
        yield Path(tmp)


def _trajectories(jobs: list[Job], run_dir: Path, backend: Backend | None, name: str,
                  progress: Callable[[str, int, int], None] | None) -> list[Trajectory]:
    """The jobs' trajectories through the runner (cached); a run that produced none is an error naming it."""
    sweep = run_jobs(jobs, run_dir, backend or InlineBackend(),
                     progress=(lambda done, total, _r: progress(name, done, total)) if progress else None)
    missing = [r for r in sweep.results if not r.trajectory]
    if missing:
        r = missing[0]
        raise RuntimeError(f"{name}: run {r.episode} of {r.agent} on {r.domain} produced no trajectory "
                           f"({r.termination}: {r.message})")
    return [Trajectory.load(r.trajectory) for r in sweep.results]


def design_figures(trajs: Sequence[Trajectory], labels: Sequence[str], d: Design) -> dict[str, float]:
    """MPD / MOD, split over robots (one lab) or labs (several) when the design has more than one."""
    if d.group is None:
        return repeatability(trajs)
    groups = [lab.split("/")[0] if d.group == "lab" else lab for lab in labels]
    return repeatability(trajs, groups=groups)


_RUN_SUFFIXES = (".csv", ".parquet")


def recorded_study(paths: Sequence[str | Path], map_name: str = "loop_3x3") -> RepeatabilityResult:
    """MPD / MOD of runs recorded in real labs: one design per call, laid out as ``LAB/ROBOT/run.csv``.

    Each path is a folder of that layout (the design is read from it: labs × robots × runs; a folder
    of run files is one robot of one lab) or run files (one robot). Files need t, x, y, theta in the
    map frame (``proxybench score``'s import); lane poses are recomputed from ``map_name``.
    """
    from proxybench.tasks.trajectory import Trajectory as T

    found: list[tuple[str, str, Path]] = []
    for p in map(Path, paths):
        if p.is_file():
            found.append(("lab", "robot", p))
        elif p.is_dir():
            for f in sorted(p.rglob("*")):
                if f.suffix in _RUN_SUFFIXES and f.is_file():
                    parts = f.relative_to(p).parts
                    lab, robot = (parts[-3], parts[-2]) if len(parts) >= 3 else ("lab", parts[-2] if len(parts) == 2
                                                                                 else "robot")
                    found.append((lab, robot, f))
        else:
            raise FileNotFoundError(f"{p}: no such file or folder")
    if len(found) < 2:
        raise ValueError(f"repeatability needs at least 2 recorded runs, found {len(found)} in {list(map(str, paths))}")
    trajs = []
    for lab, robot, f in found:
        tr = T.read(f, map_name)
        tr.meta.update({"lab": lab, "robot": robot, "source": DomainKind.RECORDED, "file": str(f)})
        trajs.append(tr)
    labs = list(dict.fromkeys(lab for lab, _, _ in found))
    robots = list(dict.fromkeys((lab, r) for lab, r, _ in found))
    per = [sum(1 for x in found if (x[0], x[1]) == g) for g in robots]
    d = Design(len(labs), max(1, len(robots) // len(labs)), max(per))
    labels = [f"{lab}/{robot}" for lab, robot, _ in found]
    name = f"recorded {d.label}"
    notes = {name: f"{len(found)} runs from {len(labs)} lab(s), {len(robots)} robot(s); runs per robot: {per}"}
    designs = {name: DesignResult(d, trajs, labels, design_figures(trajs, labels, d))}
    return RepeatabilityResult(designs, DomainKind.RECORDED, notes)


def robot_study(agent: str, commands: Mapping[str, str], runs: int = 3, seconds: float = 30.0,
                map_name: str = "loop_3x3", seed: int = 0, start: tuple[float, float, float] | None = None,
                progress: Callable[[str, int, int], None] | None = None,
                options: RobotNodeOptions | None = None, frame_rate: float = DEFAULT_FRAME_RATE,
                run_dir: str | Path | None = None,
                ) -> RepeatabilityResult:
    """``runs`` runs of ``agent`` on each robot node (name → command on the robot protocol): 1 × robots × runs.

    The robots are whatever the commands drive — physical robots' bridges or simulators; the result
    says ``source: robot node`` and names the commands. Every run asks for the same start pose. ``options``:
    how each node is started (a ``RobotNodeOptions``; None: its defaults); ``frame_rate`` [Hz]: what each is
    asked to step at. The runs are runner jobs on robot domains, cached in ``run_dir`` (None: a temporary
    folder): a study that stopped resumes without driving the robots again.
    """
    if not commands:
        raise ValueError("robot_study needs at least one robot command")
    if start is None:
        start = start_pose(map_name, seed, reality_params())
    d = Design(1, len(commands), runs)
    trajs, labels = [], []
    with _folder(run_dir) as folder:
        for r, (name, cmd) in enumerate(commands.items()):
            dom = DomainSpec.robot(cmd, frame_rate=frame_rate, name=name, options=options)
            jobs = [Job(AgentSpec(agent), dom, map_name, i, seed * 1000 + 100 * r + i, seconds, pose=start)
                    for i in range(runs)]
            for i, tr in enumerate(_trajectories(jobs, folder, None, name, progress)):
                tr.meta.update({"robot": name, "run": i, "command": cmd})
                trajs.append(tr)
                labels.append(name)
    label = f"robot nodes {d.label}"
    notes = {label: "; ".join(f"{n}: {c}" for n, c in commands.items())}
    return RepeatabilityResult({label: DesignResult(d, trajs, labels, design_figures(trajs, labels, d))}, "robot node",
                               notes)


def run_repeatability(cfg: RepeatabilityConfig,
                      progress: Callable[[str, int, int], None] | None = None) -> RepeatabilityResult:
    """The study ``cfg`` names: its recorded runs, its robot nodes, or its designs on the reality model."""
    if cfg.recorded:
        return recorded_study(cfg.recorded, cfg.map)
    if cfg.robots:
        return robot_study(cfg.agent, dict(cfg.robots), cfg.runs or 3, cfg.seconds, cfg.map, cfg.seed,
                           progress=progress, options=cfg.robot_options)
    designs = dict(Design.parse(d) for d in cfg.designs) if cfg.designs else None
    if cfg.runs is not None:
        designs = {k: Design(d.labs, d.robots, cfg.runs) for k, d in (designs or DESIGNS).items()}
    return repeatability_study(cfg.agent, designs, cfg.seconds, cfg.map, cfg.seed,
                               placement=(cfg.placement_cm / 100.0, cfg.placement_deg), progress=progress)
