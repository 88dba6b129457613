"""The work of one leased job, in a process of its own: agent, episodes, checks, report.

The evaluator loop runs ``python -m proxybench.evaluator.run JOB_DIR --parent PID`` per job, so that it
can kill the whole job (lease lost, SIGTERM) without killing itself, and so that a crash in the job
cannot take the evaluator down. The worker reads ``JOB_DIR/job.json`` (a :class:`~.job.WorkerJob`: the typed
lease and how to run it) and writes ``progress.json`` as
episodes finish; it sends the outcome through a pipe only it holds (``--outcome-fd``), never a file an
agent could forge, and dies with its parent. Agent packages run in the sandbox (:mod:`.sandbox`) as
another user, in their own PID namespace, and see none of the job's folder.

Before the episodes, the agent checker (:meth:`_Job.agent_contract`) runs on the agent. Who is at fault
decides the status: :class:`SubmissionFault` (archive refused, agent node crashed, hung or misbehaved, in the
agent contract or in an episode, privileged agent on a camera-only benchmark) → ``failed``;
:class:`HostFault` (this host cannot do it: target not compliant, sandbox unusable, benchmark too new for
this evaluator, disk full) → ``host-error``; any other exception is a bug of ours → ``error``.
"""

from __future__ import annotations

import argparse
import ctypes
import errno
import json
import logging
import os
import signal
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from proxybench.evaluator.job import WorkerJob
from proxybench.evaluator.outcome import Artifact, Fault, HostFault, Outcome, SubmissionFault

__all__ = ["main", "run_job"]

log = logging.getLogger("proxybench.evaluator.job")
UNSAFE_BANNER = ("UNSAFE SANDBOX: this evaluator ran the agent package outside the agent user's sandbox "
                 "(developer flag --dev-unsafe-same-user); do not trust this result")


def _write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data))
    tmp.replace(path)


def _log_to(path: Path) -> logging.Handler:
    """Send the job's log (and the runner's warnings) to ``path`` only, replacing the previous file."""
    root = logging.getLogger("proxybench")
    for h in list(root.handlers):
        if getattr(h, "_job_log", False):
            root.removeHandler(h)
            h.close()
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s", "%Y-%m-%d %H:%M:%S"))
    handler._job_log = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    return handler


def _admitted(bench, spec):
    """``spec``, unless ``bench`` is camera-only and the agent reads the true lane pose
    (:func:`~proxybench.runner.jobs.is_privileged`: a zoo agent's flag, an SDK program's ``privileged`` option; a
    checkpoint or an AIDO node is camera-only until its handshake says otherwise, which the episodes enforce)."""
    from proxybench.runner.jobs import is_privileged

    if bench is not None and bench.camera_only and is_privileged(spec):  # None: no benchmark read (a package check)
        raise SubmissionFault(f"agent {spec.name!r} is privileged (reads the true lane pose); benchmark "
                              f"{bench.name!r} admits camera-only agents")
    return spec


def _is_image(path: Path) -> bool:
    """Whether the submission's archive is a container image rather than a package (told by its content, as the
    server told it on upload)."""
    from proxybench.protocol.images import is_image_archive

    with path.open("rb") as f:
        return is_image_archive(f)


class _Job:
    """One job's work; fills :attr:`outcome` as it goes, so a fault still reports what was done."""

    def __init__(self, job_dir: Path, job: WorkerJob):
        self.dir = job_dir
        self.job = job
        self.lease = job.lease
        self.outcome = Outcome("success")
        self.phase = "setup"
        self.unsafe = False  # an agent package ran outside the safe sandbox (developer's flag)
        self.ground_truth = True  # the target reports the true lane pose (its compliance probe says)
        self.extra_wall_s = 0.0  # wall-clock time the lab added to the job's budget (an Autolab's re-runs)

    def progress(self, done: int, total: int) -> None:
        state = {"phase": self.phase, "done": done, "total": total}
        if self.extra_wall_s:
            state["extra_wall_s"] = self.extra_wall_s
        _write_json(self.dir / "progress.json", state)

    def allow_extra_wall(self, seconds: float) -> None:
        """Give the job ``seconds`` more of wall-clock time (an Autolab running an invalid episode again: the lab's
        time, which must not make the agent's job ``failed`` for running past its budget); the evaluator reads it
        from ``progress.json``."""
        self.extra_wall_s += max(0.0, seconds)
        self.progress(0, 0)

    # -- setup -------------------------------------------------------------------------------------

    def benchmark(self, test_seed: int | None = None):
        from proxybench.tasks.benchmark import Benchmark, BenchmarkError
        from proxybench.untrusted import load_yaml

        b = self.lease.benchmark
        data = load_yaml(b.spec_yaml, max_depth=32)  # the server checked it; bounded all the same
        if test_seed is not None:
            data["episodes"] = {**data["episodes"], "seed": int(test_seed)}
            data["episodes"].pop("seeds", None)  # explicit seeds would make the hidden split the public one
        try:
            return Benchmark.from_dict(data, origin=f"{b.name} v{b.version}")
        except BenchmarkError as exc:
            raise HostFault(f"this evaluator (proxybench {self.job.evaluator.version}) cannot read the "
                            f"benchmark: {exc}") from None

    def agent(self, bench):
        from proxybench.agents.zoo import ZOO
        from proxybench.evaluator import sandbox as sb
        from proxybench.protocol.package import PackageError
        from proxybench.runner.jobs import AgentSpec

        sub = self.lease.submission
        if sub.agent:
            name = sub.agent
            if name not in ZOO:
                raise HostFault(f"built-in agent {name!r} is unknown to this evaluator (proxybench "
                                f"{self.job.evaluator.version}); a newer evaluator can run it")
            log.info("agent: built-in %r (in-process)", name)
            return _admitted(bench, AgentSpec(name))
        isolation = self.job.isolation
        if not isolation.usable:  # checked before unpacking: nothing of the stranger's is touched
            raise HostFault(isolation.problem)
        if _is_image(self.dir / "agent.archive"):
            return _admitted(bench, self.image_agent())
        archive = (self.dir / "agent.archive").read_bytes()
        try:
            manifest = sb.prepare_agent(archive, sub.archive_sha256, self.dir / "agent")
        except PackageError as exc:
            raise SubmissionFault(f"agent archive refused: {exc}") from None
        except sb.ArchiveMismatch as exc:
            raise HostFault(str(exc)) from None
        try:  # FIFO transport: a folder of FIFOs beside the package, in the job folder (mode 700)
            spec = sb.package_spec(manifest, self.dir / "agent", self.job.limits, isolation)
        except sb.SandboxError as exc:
            raise HostFault(str(exc)) from None
        self.unsafe = not isolation.safe
        log.log(logging.WARNING if self.unsafe else logging.INFO,
                "agent: package %r (%s), command %s, transport %s; sandbox: %s", manifest.name,
                (sub.archive_sha256 or "")[:12], manifest.command, manifest.transport, isolation.note)
        return _admitted(bench, spec)

    def image_agent(self):
        """The job's agent from a container image (the submission's archive is one): hash-checked, checked and
        unpacked into this evaluator's image cache (or found there), run in the sandbox with its root file system
        (:func:`~proxybench.evaluator.image_agent.image_spec`). The image's faults are the submission's; missing
        tools or a sandbox that cannot run images, this host's."""
        import hashlib

        from proxybench.evaluator.image_agent import image_spec, images_problem
        from proxybench.evaluator.sandbox import SandboxError
        from proxybench.protocol.images import ImageError

        sub, isolation = self.lease.submission, self.job.isolation
        if problem := images_problem(isolation):
            raise HostFault(f"this evaluator cannot run container images: {problem}")
        path = self.dir / "agent.archive"
        sha = hashlib.sha256()
        with path.open("rb") as f:
            while chunk := f.read(1 << 20):
                sha.update(chunk)
        if sha.hexdigest() != sub.archive_sha256:
            raise HostFault(f"archive hash is {sha.hexdigest()}, not the submitted {sub.archive_sha256}: refusing "
                            "to run it")
        name = (sub.manifest or {}).get("name") or sub.label
        try:
            spec = image_spec(str(name)[:64], path, isolation, limits=self.job.limits)
        except ImageError as exc:
            raise SubmissionFault(f"image refused: {str(exc).replace(f'image {path}: ', '')}") from None
        except SandboxError as exc:
            raise HostFault(str(exc)) from None
        self.unsafe = not isolation.safe
        log.log(logging.WARNING if self.unsafe else logging.INFO, "agent: image %r (%s), command %s; sandbox: %s",
                spec.name, (sub.archive_sha256 or "")[:12], spec.command.split(" -- ", 1)[-1], isolation.note)
        return spec

    def agent_contract(self, bench, spec) -> None:
        """The agent checker on the job's agent before its episodes (``proxybench.testing.AgentContract`` on a second
        of the benchmark's frames). ``commands`` decides: an agent whose answers are not wheel commands (or that
        fails on the observations the benchmark gives it) would fail every episode, so it is refused here, named,
        with the node's failure in ``agent_failures`` as an episode's would be (a built-in agent failing it is a
        bug of ours). The privileged flag's honesty is reported, not enforced (the benchmark's camera-only rule is);
        determinism and isolation, which cost fresh node starts, are `proxybench agent check`'s."""
        from proxybench.protocol.failures import AgentFailure
        from proxybench.testing import AgentContract, ContractReport, StreamSpec

        self.phase = "agent-contract"
        stream = StreamSpec(map=bench.map, params=bench.domain_params(), seconds=min(1.0, bench.duration))
        contract = AgentContract.for_spec(spec, stream=stream)
        report = contract.run(["commands"])
        if report.ok:  # one node start more at most (a privileged node's), none for a camera-only node
            more = contract.run(["privileged"]).results
            report = ContractReport(report.contract, report.subject, report.results + more)
        self.outcome.public_report["agent_contract"] = report.to_dict()
        for r in report.results:
            log.log(logging.INFO if r.passed else logging.WARNING, "agent contract %s", r.line())
        commands = report.results[0]
        if commands.passed:
            return
        if spec.command is None:
            raise RuntimeError(f"built-in agent {spec.name!r} fails the agent contract: {commands.reason}")
        text = f"the agent failed the agent contract before its episodes: commands: {commands.reason}"
        if isinstance(commands.error, AgentFailure):
            exc = commands.error
            self.check_sandbox([exc.stderr_tail])
            self.outcome.public_report["agent_failures"] = [
                {"episode": "agent contract", "reason": exc.reason, "message": commands.reason,
                 "exit_code": exc.exit_code, "stderr_tail": list(exc.stderr_tail)[-20:]}]
            if exc.stderr_tail:
                text += "\nlast lines the agent wrote to stderr:\n" + "\n".join("  " + line
                                                                             for line in exc.stderr_tail[-15:])
        raise SubmissionFault(text)

    # -- running -----------------------------------------------------------------------------------

    def evaluate(self, bench, spec, split: str, target: bool):
        """Run the split's episodes: in the benchmark's domain, or on the target (robot node or reality model).

        Every kind goes through the runner (:func:`~proxybench.runner.evaluate.evaluate_benchmark`): the same
        jobs, starts, routes and trajectory files; a robot node is a :class:`~proxybench.runner.jobs.DomainSpec`.
        """
        from proxybench.domain.events import Termination
        from proxybench.protocol.failures import AgentFailure
        from proxybench.runner.backends import InlineBackend
        from proxybench.runner.episode import PrivilegedAgentError
        from proxybench.runner.evaluate import evaluate_benchmark
        from proxybench.runner.jobs import DomainSpec, is_privileged
        from proxybench.tasks.benchmark import BenchmarkError

        self.phase = split
        robot = self.job.robot_cmd if target else None
        where = f"robot node {robot!r}" if robot else "the reality model" if target else \
            f"domain {bench.domain.named or 'of the benchmark'}"
        log.info("%s: %d episodes of %g s on %s, in %s", split, len(bench.episode_specs()), bench.duration,
                 bench.map, where)
        domain: str | DomainSpec | None = "reality" if target else None
        if robot:
            if is_privileged(spec) and not self.ground_truth:
                raise HostFault(f"the target robot cannot run this job: robot node {robot!r} reports no true lane "
                                f"pose, which the privileged agent {spec.name!r} needs")
            domain = DomainSpec.robot(robot, frame_rate=bench.frame_rate, options=self.robot_options())
        try:
            ev = evaluate_benchmark(bench, [spec], self.dir / "runs" / split, InlineBackend(), domain=domain,
                                    privileged=is_privileged, progress=self.progress)
        except AgentFailure as exc:  # the node could not even be started or handshaken
            self.check_sandbox([exc.stderr_tail])
            raise SubmissionFault(f"agent node failed in the {split} episodes: {exc}") from None
        except BenchmarkError as exc:
            if robot:
                raise HostFault(f"the target robot cannot run this job: {exc}") from None
            raise
        except PrivilegedAgentError as exc:
            raise SubmissionFault(str(exc)) from None
        lost = [r for r in ev.sweep.results if r.termination is Termination.ROBOT_FAILURE]
        if lost:
            raise HostFault(f"the target robot cannot run this job: {lost[0].message}")
        return ev

    def check_sandbox(self, stderr_tails: list[list[str]]) -> None:
        """An agent that failed with the sandbox's own words on its stderr: is the sandbox still working here?

        The agent writes its stderr too, so its words decide nothing: the probe (a fresh sandbox running
        Python) does. Broken → :class:`HostFault` (the job goes to another evaluator); else the agent's fault.
        """
        from proxybench.evaluator import sandbox as sb

        if not any(line.startswith(("bwrap:", "_confine:")) for tail in stderr_tails for line in tail[:5]):
            return
        isolation = self.job.isolation
        if isolation.kind != "bwrap":
            return
        problem = sb.probe(isolation)
        if problem is not None:
            raise HostFault(f"the sandbox stopped working on this host: {problem}")
        log.info("the agent's failure mentions the sandbox, but the sandbox works here: the agent's fault")

    def split(self, bench, spec, split: str, target: bool, domain_kind: str, hidden: bool):
        from proxybench.domain.kinds import ROBOT_NODE
        from proxybench.evaluator.report import pack_trajectories, summarize

        ev = self.evaluate(bench, spec, split, target)
        summary = summarize(ev, split, domain_kind=domain_kind,
                            extra={"benchmark_version": self.lease.benchmark.version})
        if hidden:
            self.outcome.hidden_report = summary.report
        else:
            self.outcome.public_report.update(summary.report)
        zip_path = pack_trajectories(ev, self.dir / f"trajectories-{split}.zip")
        self.outcome.artifacts.append(Artifact(zip_path.name, str(zip_path), hidden, "application/zip"))
        log.info("%s: terminations %s; %s", split, summary.report["terminations"],
                 ", ".join(f"{k}={v:.3f}" if v is not None else f"{k}=null"
                           for k, v in summary.scores.items() if k in summary.report["criteria"]))
        if summary.problems:
            text = f"invalid {split} data: " + "; ".join(summary.problems[:5])
            if not domain_kind.startswith(ROBOT_NODE):
                raise RuntimeError(text + " (our own simulator should never produce this)")
            raise HostFault(text)
        if summary.failures:
            self.check_sandbox([f.get("stderr_tail") or [] for f in summary.failures])
            if hidden:
                raise SubmissionFault(f"the agent failed in {len(summary.failures)} hidden test episodes "
                                      "(details are shown to the operators only)")
            raise SubmissionFault(summary.failure_message())
        if not hidden and self.job.video:
            self.video(ev, bench)
        return summary

    def video(self, ev, bench) -> None:
        from proxybench.evaluator.report import topdown_video

        first = min(ev.sweep.results, key=lambda r: r.episode)
        if not first.trajectory:
            return
        try:
            path = topdown_video(first.trajectory, self.dir / "validation-episode-0.mp4", bench.frame_rate)
        except Exception as exc:  # a missing codec must not cost a result: the video is optional
            log.warning("no video of the first episode: %s", exc)
            return
        self.outcome.artifacts.append(Artifact(path.name, str(path), False, "video/mp4"))

    def robot_options(self):
        """How the evaluator's robot node is started (``--robot-cwd``, ``--robot-transport``, ...)."""
        from proxybench.protocol.options import RobotNodeOptions

        return RobotNodeOptions(**self.job.robot_options)

    def compliance(self, bench) -> str:
        """Check the target before a target job; its ``domain_kind``. Not compliant: :class:`HostFault`."""
        from proxybench.evaluator.compliance import check_target
        from proxybench.runner.evaluate import benchmark_domain
        from proxybench.runner.jobs import DomainSpec

        self.phase = "compliance"
        robot = self.job.robot_cmd
        if robot:
            log.info("target job: the target is the robot node %r", robot)
            domain = DomainSpec.robot(robot, frame_rate=bench.frame_rate, options=self.robot_options())
        else:
            log.info("target job: the target is the reality model, a simulated stand-in (no real robot here)")
            domain = benchmark_domain(bench, "reality")
        report, probe = check_target(bench, domain)
        self.ground_truth = probe is not None and probe.ground_truth
        self.outcome.public_report["compliance"] = report.to_dict()
        for c in report.checks:
            log.info("compliance %s: %s: %s", c.name, "ok" if c.ok else "FAILED", c.detail)
        if not report.ok:
            raise HostFault(f"target not compliant ({report.target}): {report.failures()}")
        return report.domain_kind

    def run(self) -> Outcome:
        features = set(self.job.job_features)
        unknown = features - {"sim", "target"} - ({"autolab"} if self.job.autolab is not None else set())
        if unknown:
            raise HostFault(f"job needs feature(s) {', '.join(sorted(unknown))} that this evaluator cannot provide")
        if "autolab" in features:  # measured by a lab's watchtowers: its own module
            from proxybench.evaluator.autolab import run_autolab

            return run_autolab(self)
        bench = self.benchmark()
        target = "target" in features
        from proxybench.runner.evaluate import benchmark_domain

        kind = str(benchmark_domain(bench).kind)
        self.outcome.public_report.update(evaluator=self.job.evaluator.model_dump(mode="json"),
                                          sandbox=self.job.isolation.report())
        if target:
            kind = self.compliance(bench)
        self.outcome.public_report["domain_kind"] = kind
        spec = self.agent(bench)
        self.agent_contract(bench, spec)
        public = self.split(bench, spec, "validation", target, kind, hidden=False)
        self.outcome.public_scores = public.scores
        test_seed = self.lease.benchmark.test_seed
        if test_seed is not None:
            log.info("validation done; the hidden test episodes are logged apart (shown to operators only)")
            _log_to(self.dir / "evaluator-hidden.log")
            hidden = self.split(self.benchmark(test_seed), spec, "test", target, kind, hidden=True)
            self.outcome.hidden_scores = hidden.scores
        self.outcome.message = f"{len(bench.episode_specs())} validation episodes" + \
            (" and the hidden test episodes" if test_seed is not None else "") + " evaluated"
        return self.outcome


def run_job(job_dir: Path) -> Outcome:
    """Do the job in ``job_dir`` and return its outcome (never raises for the job's own failures)."""
    job_dir = Path(job_dir)
    _log_to(job_dir / "evaluator.log")
    work = WorkerJob.read(job_dir / "job.json")
    lease = work.lease
    log.info("job %s (lease %s…, attempt %s) on evaluator %r: benchmark %s v%s, submission %s",
             lease.job_id, lease.lease_id[:8], lease.attempt, work.evaluator.name, lease.benchmark.name,
             lease.benchmark.version, lease.submission.id)
    job = _Job(job_dir, work)
    t0 = time.perf_counter()
    try:
        outcome = job.run()
    except Fault as exc:
        outcome = job.outcome
        outcome.status, outcome.message = exc.status, str(exc)
        outcome.public_scores, outcome.hidden_scores = {}, {}
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.ENOMEM):
            raise
        outcome = job.outcome
        outcome.status, outcome.message = "host-error", f"out of resources on this host: {exc}"
    except Exception as exc:
        log.error("evaluator bug:\n%s", traceback.format_exc())
        outcome = job.outcome
        outcome.status = "error"
        outcome.message = f"evaluator error (not the submission's fault): {type(exc).__name__}: {exc}"
        outcome.public_scores, outcome.hidden_scores = {}, {}
    if job.unsafe:
        outcome.message = f"{UNSAFE_BANNER}\n{outcome.message}"
    log.log(logging.INFO if outcome.status == "success" else logging.WARNING, "outcome %s after %.1f s: %s",
            outcome.status, time.perf_counter() - t0, outcome.message)
    logging.getLogger("proxybench").handlers.clear()
    for name, hidden in (("evaluator.log", False), ("evaluator-hidden.log", True)):
        if (job_dir / name).is_file():
            outcome.artifacts.append(Artifact(name, str(job_dir / name), hidden, "text/plain"))
    return outcome


def _die_with(parent: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG: the evaluator killed (-9) takes its job along
    if os.getppid() != parent:
        sys.exit(3)


def _warm_up() -> None:
    """Import what every job needs, so that a spare worker starts its job at once."""
    import proxybench.evaluator.report
    import proxybench.evaluator.sandbox
    import proxybench.protocol
    import proxybench.runner.evaluate  # noqa: F401 - imported for its import time


def _wait_for_job() -> Path | None:
    """A spare worker's job folder, from the evaluator on stdin; its output then goes to the job's worker.log."""
    line = sys.stdin.readline().strip()
    if not line:
        return None  # the evaluator closed without a job for us
    job_dir = Path(line)
    folder = os.open(job_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:  # the evaluator made it (mode 700, ours) in its private work folder: anything else is not our job
        st = os.fstat(folder)
        if st.st_uid != os.geteuid() or st.st_mode & 0o077:
            raise SystemExit(f"job folder {job_dir} is not this user's private folder: refusing it")
        fd = os.open("worker.log", os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600,
                     dir_fd=folder)
    finally:
        os.close(folder)
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    return job_dir


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m proxybench.evaluator.run", description=__doc__.splitlines()[0])
    p.add_argument("job_dir", type=Path, nargs="?", help="the job's folder (else: read from stdin, --spare)")
    p.add_argument("--parent", type=int, help="the evaluator's pid: die with it")
    p.add_argument("--outcome-fd", type=int, help="pipe to the evaluator for the outcome [stdout]")
    p.add_argument("--spare", action="store_true", help="import everything first, then read the job's folder "
                                                        "from stdin (started ahead of its job)")
    args = p.parse_args(argv)
    if args.parent is not None and sys.platform.startswith("linux"):
        _die_with(args.parent)
    job_dir = args.job_dir
    if args.spare:
        _warm_up()
        job_dir = _wait_for_job()
        if job_dir is None:
            return 0
    if job_dir is None:
        p.error("give JOB_DIR or --spare")
    outcome = run_job(job_dir)
    with os.fdopen(args.outcome_fd if args.outcome_fd is not None else sys.stdout.fileno(), "w",
                   closefd=args.outcome_fd is not None) as channel:
        outcome.send(channel)
    return 0


if __name__ == "__main__":
    sys.exit(main())
