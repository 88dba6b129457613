"""The evaluator loop: lease a job, keep the lease alive, run the job in a worker process, upload, repeat.

Many evaluators on many machines pull from one server over HTTP (from behind NAT: they only ever call
out). Per job:

1. ``POST /jobs/lease`` with this evaluator's name and features (nothing → wait ``poll`` s, ask again);
2. a heartbeat thread extends the lease every ``lease_seconds / 4``; a 409 means the lease was lost
   (it lapsed and another evaluator has the job, or an operator aborted it): the worker is killed and the
   work dropped, nothing is uploaded;
3. the submission's archive is downloaded (hash-checked), and ``python -m proxybench.evaluator.run`` does
   the job in its own process group (:mod:`.run`), dying with this process if it is killed; its outcome
   comes back through a pipe only it holds, and is taken only from a worker that exited normally (a
   worker that died is the evaluator's ``error``); artifacts are plain files of the job folder, which
   only the evaluator's user can enter;
4. artifacts are uploaded by content hash, then the result is posted, retried through network failures
   (the server stores it exactly once per lease, so a retry after a lost reply is harmless).

An Autolab evaluator runs one such loop per robot of its lab at once (:mod:`.robots`): a job is leased only
with a free robot in hand, and holds it until its result is posted.

SIGTERM / SIGINT (:meth:`Evaluator.stop`) end the loop; a job being worked on is killed and reported as
``aborted`` (as ``host-error`` if its work had not started, so that it goes back to the queue).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import signal
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from proxybench import __version__
from proxybench.autolab.lab import Lab
from proxybench.client import ServerClient, ServerError
from proxybench.contract import Lease, LeasedBenchmark, ResultUpload
from proxybench.evaluator.job import EvaluatorInfo, WorkerJob
from proxybench.evaluator.outcome import Artifact, Outcome
from proxybench.evaluator.robots import RobotLeases
from proxybench.evaluator.sandbox import AGENT_USER, Isolation, Limits, detect_isolation
from proxybench.evaluator.workdir import JobDir, StateDir
from proxybench.evaluator.worker import Worker, job_artifacts_only

__all__ = ["Evaluator", "EvaluatorConfig", "Reporter"]

log = logging.getLogger("proxybench.evaluator")
_MAX_MESSAGE = 100_000
@dataclass(frozen=True)
class EvaluatorConfig:
    """One evaluator's settings. ``features``: what it offers (``sim``, ``target``); ``poll`` [s] between
    lease attempts when the queue is empty; ``robot_cmd``: the robot node that target jobs run on (default:
    the reality model), ``robot_options``: how to start it (the non-default fields of ``RobotNodeOptions``);
    ``post_retry_s`` [s]: how long a result upload is retried; ``agent_user``: the
    unprivileged user agent packages run as; ``dev_unsafe``: the developer's flag that lets them run as the
    evaluator's own user where that is impossible (every report says so); ``start_allowance_s`` [s]: what a
    job may take beyond its benchmark's wall-clock budget (starting the worker, agent and target, the
    video): past both, the job ends ``failed``; ``autolab``: the lab whose robot and watchtowers run Autolab
    jobs (feature ``autolab``, :mod:`.autolab`)."""

    name: str
    work_dir: Path
    features: tuple[str, ...] = ("sim",)
    poll: float = 2.0
    agent_user: str = AGENT_USER
    dev_unsafe: bool = False
    limits: Limits = field(default_factory=Limits)
    video: bool = True
    keep_work: bool = False
    robot_cmd: str | None = None
    robot_options: dict[str, Any] = field(default_factory=dict)
    post_retry_s: float = 600.0
    start_allowance_s: float = 300.0
    autolab: Lab | None = None


class Reporter:
    """What the loop tells its user; the CLI draws it with rich, the default logs it."""

    def job_started(self, lease: Lease) -> None:
        b, s = lease.benchmark, lease.submission
        log.info("job %s: %s v%s, submission %s (%s)", lease.job_id, b.name, b.version, s.id,
                 s.agent or (s.manifest or {}).get("name", "archive"))

    def job_progress(self, lease: Lease, progress: dict[str, Any]) -> None:
        pass

    def job_finished(self, lease: Lease, status: str, message: str) -> None:
        log.info("job %s: %s %s", lease.job_id, status, message.splitlines()[0] if message else "")

    def note(self, text: str) -> None:
        log.info("%s", text)


def _extra_wall(progress: dict[str, Any] | None, budget: float | None) -> float:
    """The wall-clock time the worker added to the job's budget (``extra_wall_s`` in its progress: an Autolab's
    re-runs of invalid episodes, the lab's time), at most ten budgets (the most retries a benchmark may ask)."""
    try:
        extra = float((progress or {}).get("extra_wall_s", 0.0))
    except (TypeError, ValueError):
        return 0.0
    return min(max(extra, 0.0), 10.0 * (budget or 0.0)) if math.isfinite(extra) else 0.0


class _Heartbeat(threading.Thread):
    """Extends one lease until stopped; sets ``lost`` on a 409 (or 404) answer."""

    def __init__(self, client: ServerClient, lease: Lease, name: str, job: JobDir, wake: threading.Event):
        super().__init__(name=f"heartbeat-{lease.job_id}", daemon=True)
        self.client, self.lease, self.evaluator, self.job, self.wake = client, lease, name, job, wake
        self.interval = max(0.2, lease.lease_seconds / 4)
        self.done = threading.Event()
        self.lost = threading.Event()
        self.lost_reason = ""
        self.progress: dict[str, Any] | None = None

    def run(self) -> None:
        while not self.done.wait(self.interval):
            with contextlib.suppress(OSError, ValueError):
                self.progress = json.loads(self.job.read("progress.json", 1 << 16))
            try:
                self.client.heartbeat(self.lease.job_id, self.lease.lease_id, self.evaluator, self.progress)
            except ServerError as exc:
                if exc.status in (404, 409):
                    self.lost_reason = exc.message
                    self.lost.set()
                    self.wake.set()
                    return
                log.warning("heartbeat for job %s failed (%s); trying again", self.lease.job_id, exc)

    def stop(self) -> None:
        self.done.set()
        self.join(timeout=30)


class Evaluator:
    """``Evaluator(server_url, token, config).run()``: pull and evaluate jobs until stopped."""

    def __init__(self, server: str, token: str, config: EvaluatorConfig, reporter: Reporter | None = None):
        self.config = config
        self.server, self._token = server, token
        self.client = ServerClient(server, token)
        self.reporter = reporter or Reporter()
        self.isolation: Isolation = detect_isolation(config.agent_user, config.dev_unsafe)
        work = os.path.realpath(config.work_dir)
        for root in self.isolation.runtime:
            if work == root or work.startswith(root.rstrip("/") + "/"):
                raise RuntimeError(f"work dir {config.work_dir} lies inside {root}, which agents see (the runtime): "
                                   "choose a work dir elsewhere")
        self._stopping = threading.Event()
        self._wake = threading.Event()
        self.stop_reason = ""
        self.jobs_done = 0
        self.work = StateDir(config.work_dir)  # this user's only (mode 700), locked: see evaluator/workdir.py
        self._spare: Worker | None = None
        self._spare_lock = threading.Lock()  # the spare is shared by the slots of an Autolab's robots
        self._keep_spare = False  # run(): start the next job's worker as soon as one is free
        # Workers are forked from this one thread, which lives as long as the evaluator: a worker dies with the
        # *thread* that forked it (PR_SET_PDEATHSIG), and a slot's thread ends while a spare it made may be
        # running another slot's job (that job's worker was killed, -9, with no outcome)
        self._spawner = ThreadPoolExecutor(max_workers=1, thread_name_prefix="worker-spawner")
        #: an Autolab's robots: a job is leased only with a free one in hand (one slot per robot in run())
        self.robots = RobotLeases(config.autolab) if config.autolab is not None else None
        self.lab_world = None  # the lab's shared world (world: shared), started by run()
        self._worker_env = {k: v for k, v in os.environ.items() if not k.startswith("PROXYBENCH_TOKEN")}
        for stale in self.work.entries("job-"):  # left by a killed evaluator: never resumed, the lease is gone
            self.work.remove(stale)

    # -- control -----------------------------------------------------------------------------------

    def stop(self, why: str = "stopped") -> None:
        """End the loop (callable from a signal handler): a running job is killed and reported aborted."""
        self.stop_reason = why
        self._stopping.set()
        self._wake.set()

    def install_signal_handlers(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda signum, _frame: self.stop(signal.Signals(signum).name))

    def run(self, once: bool = False) -> int:
        """Evaluate jobs until :meth:`stop` (or, with ``once``, after one lease attempt); jobs done."""
        target = ("" if "target" not in self.config.features else
                  f"; target: robot node {self.config.robot_cmd!r}" if self.config.robot_cmd else
                  "; target: the reality model (a simulated stand-in, no real robot)")
        self.reporter.note(f"evaluator {self.config.name!r} (proxybench {__version__}) → {self.server}; features "
                           f"{','.join(self.config.features)}{target}; sandbox: "
                           f"{self.isolation.note or 'none (agent packages are refused)'}")
        if not self.isolation.usable:
            log.warning("%s; their jobs end in host-error and go to other evaluators", self.isolation.problem)
        elif not self.isolation.safe:
            log.warning("%s", self.isolation.note)
        lab = self.config.autolab
        if lab is not None and lab.world == "shared" and self.lab_world is None:
            from proxybench.evaluator.lab_world import LabWorldProcess

            self.lab_world = LabWorldProcess(lab)
            self.reporter.note(f"lab {lab.name!r}: its virtual robots share one world (served at "
                               f"{self.lab_world.address.path})")
        slots = len(self.robots) if self.robots is not None else 1
        if slots > 1 and not self._robots_apart():
            self.reporter.note(f"lab {self.config.autolab.name!r}: one job at a time: without the safe sandbox the "
                               "virtual robots share this host's network and its port 7501")
            slots = 1
        if slots == 1:
            self._loop(once)
        else:
            self.reporter.note(f"lab {self.config.autolab.name!r}: up to {slots} jobs at once, one on each of robots "
                               f"{', '.join(self.robots.robots)}")
            self._slots(slots, once)
        self.close()
        return self.jobs_done

    def _robots_apart(self) -> bool:
        """Whether each job's virtual robot gets a network namespace of its own (its own 127.0.0.1:7501): the safe
        sandbox's rule in :func:`.sandbox.sdk_package_spec`; otherwise two robots would wait for one port."""
        return self.isolation.kind == "bwrap" and self.isolation.uid is not None

    def _loop(self, once: bool) -> None:
        """Lease and run jobs one after another until stopped (with ``once``: one lease attempt)."""
        while not self._stopping.is_set():
            with self._spare_lock:
                if self._spare is None or not self._spare.ready:
                    self._spare = self._new_worker()  # imports while we wait for a job
            self._keep_spare = not once
            status = self.take_one()
            if once:
                break
            if status is None:
                self._wake.wait(self.config.poll)
                self._wake.clear()

    def _slots(self, slots: int, once: bool) -> None:
        """``slots`` loops at once (an Autolab's robots, one job each); the first error of one stops them all and is
        raised here, as the single loop's would be."""
        errors: list[BaseException] = []

        def loop() -> None:
            try:
                self._loop(once)
            except BaseException as exc:
                errors.append(exc)
                self.stop(f"a slot failed: {exc}")

        threads = [threading.Thread(target=loop, name=f"slot-{k}", daemon=True) for k in range(slots)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            raise errors[0]

    def close(self) -> None:
        """Stop the spare worker, free the lab's robots, release the server connection and the work dir."""
        if self._spare is not None:
            self._spare.kill()
            self._spare = None
        self._spawner.shutdown()
        if self.robots is not None:
            self.robots.close()
        if self.lab_world is not None:
            self.lab_world.close()
            self.lab_world = None
        self.client.close()
        self.work.close()

    def take_one(self) -> str | None:
        """Lease one job and see it through. Returns the status reported, ``lost`` (the lease was lost: work
        dropped), ``unreported`` (the server stayed unreachable), or None when no job was free (or, in an
        Autolab, no robot: then nothing is leased)."""
        robot = None
        if self.robots is not None:
            robot = self.robots.take()
            if robot is None:
                return None
        try:
            try:
                leased = self.client.lease(self.config.name, list(self.config.features), __version__)
            except ServerError as exc:
                if exc.status in (400, 401, 403, 404, 422):  # this evaluator's token or settings: won't help to retry
                    raise
                self.reporter.note(f"cannot lease a job: {exc}")
                return None
            except ValidationError as exc:  # a lease this evaluator cannot read (a server too new or too old)
                self.reporter.note(f"cannot read the server's lease reply: {exc}")
                return None
            if leased is None:
                return None
            self.reporter.job_started(leased)
            if robot is not None:
                log.info("job %s: on lab %r's robot %r", leased.job_id, self.config.autolab.name, robot)
            status = self._process(leased, robot)
            with self._spare_lock:
                self.jobs_done += 1
            return status
        finally:
            if robot is not None:
                self.robots.give_back(robot)

    # -- one job -----------------------------------------------------------------------------------

    def _features_of(self, lease: Lease) -> list[str]:
        if "features" in lease.model_fields_set:  # a server that says them (all but the oldest)
            return list(lease.features)
        try:
            return list(self.client.get(f"/jobs/{lease.job_id}").get("features", []))
        except ServerError as exc:
            log.warning("cannot read job %s's features (%s); assuming a simulation job", lease.job_id, exc)
            return ["sim"]

    def _process(self, lease: Lease, robot: str | None = None) -> str:
        try:  # job.json holds the hidden test seed: a folder of the evaluator's user only, made afresh
            job = self.work.new_job(f"job-{lease.job_id}-{lease.lease_id[:8]}")
        except OSError as exc:
            self.reporter.job_finished(lease, "host-error", f"cannot make the job folder: {exc}")
            return self._report(lease, Outcome("host-error", f"this host cannot prepare the job: {exc}"), None, None)
        heart_client = ServerClient(self.server, self._token, retry_for=max(1.0, lease.lease_seconds / 4))
        heart = _Heartbeat(heart_client, lease, self.config.name, job, self._wake)
        heart.start()
        try:
            try:
                outcome = self._work(lease, job, heart, robot)
            except OSError as exc:  # e.g. a full disk while preparing the job
                log.exception("job %s: cannot prepare the job", lease.job_id)
                outcome = Outcome("host-error", f"this host cannot prepare the job: {exc}")
            with self._spare_lock:
                if self._keep_spare and not self._stopping.is_set() and (self._spare is None or not self._spare.ready):
                    self._spare = self._new_worker()  # the next job's worker imports while this one uploads
            if heart.lost.is_set():
                self.reporter.job_finished(lease, "lost", f"lease lost, work dropped: {heart.lost_reason}")
                return "lost"
            status = self._report(lease, outcome, heart, job)
            self.reporter.job_finished(lease, status, outcome.message)
            return status
        finally:
            heart.stop()
            heart_client.close()
            job.close(remove=not self.config.keep_work)

    def _work(self, lease: Lease, job: JobDir, heart: _Heartbeat, robot: str | None = None) -> Outcome:
        sub = lease.submission
        if sub.archive_sha256:
            try:
                job.write("agent.archive", self.client.stream_artifact(sub.archive_sha256))
            except ServerError as exc:
                status = "host-error" if exc.status == 0 else "error"
                return Outcome(status, f"cannot download the submission's archive: {exc}")
        worker_job = WorkerJob(lease=lease, job_features=self._features_of(lease),
                               evaluator=EvaluatorInfo(name=self.config.name, features=list(self.config.features),
                                                       version=__version__),
                               isolation=self.isolation, limits=self.config.limits, video=self.config.video,
                               robot_cmd=self.config.robot_cmd, robot_options=dict(self.config.robot_options),
                               autolab=self.config.autolab, autolab_robot=robot,
                               lab_world=None if self.lab_world is None else self.lab_world.address)
        job.write("job.json", worker_job.model_dump_json(indent=1).encode())
        if self._stopping.is_set():
            return Outcome("host-error", f"evaluator {self.config.name!r} is shutting down ({self.stop_reason}); "
                                         "job not started")
        with self._spare_lock:  # one slot at a time: each new worker's log is made afresh under one name
            worker = self._spare if self._spare is not None and self._spare.ready else self._new_worker()
            self._spare = None
        budget = lease.benchmark.wall_budget
        deadline = math.inf if budget is None else time.monotonic() + budget + self.config.start_allowance_s
        worker.give(job.path)
        try:
            while worker.proc.poll() is None and not heart.lost.is_set() and not self._stopping.is_set():
                if time.monotonic() > deadline + _extra_wall(heart.progress, budget):
                    break
                self._wake.wait(0.25)
                self._wake.clear()  # the events themselves say what happened
                if heart.progress is not None:
                    self.reporter.job_progress(lease, heart.progress)
        finally:
            worker.kill()
        sent = worker.outcome_text()
        if heart.lost.is_set():
            return Outcome("error", "lease lost")
        if sent is not None:
            try:
                return job_artifacts_only(Outcome.parse(sent), job.path)
            except ValueError as exc:
                log.error("job %s: the worker's outcome is unusable: %s", lease.job_id, exc)
        if time.monotonic() > deadline + _extra_wall(heart.progress, budget):  # the agent answered too slowly
            outcome = Outcome("failed", self._over_budget(lease.benchmark, budget or 0.0))
        elif self._stopping.is_set():
            outcome = Outcome("aborted", f"evaluator {self.config.name!r} was stopped ({self.stop_reason}) while "
                                         "evaluating this job")
        else:
            # it died before it took the job: its output is in the spare's log
            tail = job.tail("worker.log") if job.exists("worker.log") else self.work.tail("spare-worker.log")
            outcome = Outcome("error", f"evaluator worker died (exit status {worker.proc.returncode}) without an "
                                       "outcome; last output:\n" + "\n".join(tail))
        for name, hidden in (("evaluator.log", False), ("evaluator-hidden.log", True), ("worker.log", True)):
            if job.exists(name):
                outcome.artifacts.append(Artifact(name, str(job.path / name), hidden, "text/plain"))
        return outcome

    def _over_budget(self, bench: LeasedBenchmark, budget: float) -> str:
        return (f"the job ran past its wall-clock budget of {budget + self.config.start_allowance_s:.0f} s: "
                f"{bench.wall_time_factor:g}× the simulated time of its episodes ({budget:.0f} s for "
                f"{bench.simulated_seconds:g} s per split) plus {self.config.start_allowance_s:g} s to start; "
                "the agent answered too slowly (each step may take up to its step timeout, but not every step)")

    def _new_worker(self) -> Worker:
        """A worker forked by the spawner thread (see ``__init__``), whichever thread asks."""
        log_fd = self.work.fresh_file("spare-worker.log")
        try:
            made = self._spawner.submit(Worker, log_fd, self._worker_env)
        except BaseException:  # closed: the worker would close its log itself
            os.close(log_fd)
            raise
        return made.result()

    # -- reporting ---------------------------------------------------------------------------------

    def _upload(self, artifacts: list[Artifact], heart: _Heartbeat, job: JobDir,
                lease: Lease) -> tuple[list[dict[str, Any]], list[str]]:
        refs, notes = [], []
        for a in artifacts:
            if heart.lost.is_set():
                break
            try:  # a plain file of the job folder, read through its descriptor (no link is followed)
                sha = self.client.put_artifact(job.read(a.name), a.media_type, lease=(lease.job_id, lease.lease_id))
            except (ServerError, OSError) as exc:
                notes.append(f"artifact {a.name} not uploaded: {exc}")
                continue
            refs.append({"name": a.name, "sha256": sha, "hidden": a.hidden})
        return refs, notes

    def _report(self, lease: Lease, outcome: Outcome, heart: _Heartbeat | None, job: JobDir | None) -> str:
        refs, notes = self._upload(outcome.artifacts, heart, job, lease) if heart and job else ([], [])
        message = "\n".join([outcome.message, *notes]) if notes else outcome.message
        body = {"lease_id": lease.lease_id, "evaluator": self.config.name, "status": outcome.status,
                "public_scores": outcome.public_scores, "hidden_scores": outcome.hidden_scores,
                "public_report": outcome.public_report, "hidden_report": outcome.hidden_report,
                "message": message[:_MAX_MESSAGE], "artifacts": refs}
        try:
            try:
                upload = ResultUpload.model_validate(body)  # the server's own checks, before sending
                self._post(lease, upload)
            except (ServerError, ValidationError) as exc:
                if isinstance(exc, ServerError) and exc.status != 422:
                    raise
                why = exc.message if isinstance(exc, ServerError) else str(exc)
                log.error("job %s: the result was refused (%s); reporting an error instead", lease.job_id, why)
                upload = ResultUpload(lease_id=lease.lease_id, evaluator=self.config.name, status="error",
                                      message=f"the server refused this evaluator's result: {why}"[:_MAX_MESSAGE])
                self._post(lease, upload)
                return "error"
        except ServerError as exc:
            if exc.status in (401, 403):
                raise
            if exc.status == 409:
                log.warning("job %s: result refused, the lease was lost: %s", lease.job_id, exc.message)
                return "lost"
            log.error("job %s: the result could not be delivered (%s); the lease will lapse and the job run again",
                      lease.job_id, exc)
            return "unreported"
        return outcome.status

    def _post(self, lease: Lease, body: ResultUpload) -> None:
        """POST the result; network failures and 5xx are retried for ``post_retry_s`` (stored once per lease)."""
        deadline = time.monotonic() + self.config.post_retry_s
        while True:
            try:
                self.client.result(lease.job_id, body)
                return
            except ServerError as exc:
                if (exc.status != 0 and exc.status < 500) or time.monotonic() > deadline:
                    raise
                log.warning("posting the result of job %s failed (%s); retrying", lease.job_id, exc)
                time.sleep(2.0)
