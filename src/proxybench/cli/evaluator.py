"""`proxybench evaluator`: a worker that pulls jobs from a challenges server and evaluates them."""

from __future__ import annotations

import logging
import socket
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.markup import escape

from proxybench.cli.app import app, console, err_console, fail, require_extra
from proxybench.cli.node_options import with_robot_node_options
from proxybench.cli.options import positive

if TYPE_CHECKING:
    from proxybench.contract import Lease
    from proxybench.protocol.options import RobotNodeOptions

KNOWN_FEATURES = ("sim", "target")


def _reporter():
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from proxybench.cli.progress import progress_bar
    from proxybench.evaluator import Reporter

    class RichReporter(Reporter):
        """Job lines on the console and a bar of each running job's episodes (an Autolab runs one job per robot at
        once: one live display, a bar per job, called from the evaluator's slot threads)."""

        def __init__(self) -> None:
            self.progress: Progress | None = None
            self.tasks: dict[int, Any] = {}
            self.lock = threading.Lock()

        def job_started(self, lease: Lease) -> None:
            b, s = lease.benchmark, lease.submission
            who = s.agent or (s.manifest or {}).get("name", "archive")
            with self.lock:
                console.print(f"[bold]job {lease.job_id}[/bold] (attempt {lease.attempt}): "
                              + escape(f"{b.name} v{b.version} ← submission {s.id} {s.label} [{who}]"),
                              highlight=False)
                if self.progress is None:
                    self.progress = progress_bar(TextColumn("  {task.description}"), BarColumn(),
                                                 MofNCompleteColumn(), TimeElapsedColumn(), console=console,
                                                 transient=True)
                    self.progress.start()
                self.tasks[lease.job_id] = self.progress.add_task(f"job {lease.job_id}: setting up", total=None)

        def job_progress(self, lease: Lease, progress: dict[str, Any]) -> None:
            with self.lock:
                task = self.tasks.get(lease.job_id)
                if self.progress is not None and task is not None:
                    self.progress.update(task, description=f"job {lease.job_id}: {progress.get('phase', '')} "
                                                           "episodes",
                                         completed=progress.get("done", 0), total=progress.get("total"))

        def job_finished(self, lease: Lease, status: str, message: str) -> None:
            with self.lock:
                task = self.tasks.pop(lease.job_id, None)
                if self.progress is not None and not self.tasks:  # the last running job: its last count, then gone
                    self.progress.stop()
                    self.progress = None
                elif self.progress is not None and task is not None:
                    self.progress.remove_task(task)
                colour = {"success": "green", "failed": "yellow", "lost": "yellow"}.get(status, "red")
                first = message.splitlines()[0] if message else ""
                console.print(f"  job {lease.job_id}: [{colour}]{status}[/{colour}] {escape(first[:300])}",
                              highlight=False)

        def note(self, text: str) -> None:
            console.print(escape(text), highlight=False)

    return RichReporter()


@app.command()
@with_robot_node_options()
def evaluator(
    server: str | None = typer.Option(None, "--server", envvar="PROXYBENCH_SERVER",
                                      help="challenges server URL [http://127.0.0.1:8000]"),
    token: str | None = typer.Option(None, "--token", hidden=True, help="refused: argv is visible to every user"),
    token_file: Path | None = typer.Option(None, "--token-file", help="file holding the API token (role evaluator; "
                                                                      "or $PROXYBENCH_TOKEN, $PROXYBENCH_TOKEN_FILE)"),
    name: str | None = typer.Option(None, help="this evaluator's name, unique per token [host name]"),
    features: str = typer.Option("sim", help="what this evaluator offers, comma-separated: sim, target"),
    once: bool = typer.Option(False, "--once", help="try to take one job, evaluate it, and exit"),
    poll: float = typer.Option(2.0, min=0.1, callback=positive,
                               help="seconds between lease attempts while the queue is empty"),
    work_dir: Path | None = typer.Option(None, help="folder for job files, this user's only (mode 700) "
                                                    "[root: /var/lib/proxybench-evaluator/<name>, else "
                                                    "~/.local/state/proxybench-evaluator/<name>]"),
    agent_user: str = typer.Option("proxybench-agent", help="unprivileged user that agent packages run as "
                                                            "(`proxybench sandbox setup` makes it)"),
    dev_unsafe_same_user: bool = typer.Option(False, "--dev-unsafe-same-user",
                                              help="DEVELOPMENT ONLY: where the agent user's sandbox is impossible, "
                                                   "run agent packages as this evaluator's own user (root too); "
                                                   "every report says so"),
    cpu_seconds: int = typer.Option(600, min=1, help="CPU time limit of each agent process [s]"),
    memory_mb: int = typer.Option(4096, min=64, help="address-space limit of each agent process [MiB]"),
    file_mb: int = typer.Option(256, min=1, help="largest file an agent process may write [MiB]"),
    scratch_mb: int = typer.Option(256, min=1, help="size of the agent's writable /scratch [MiB]; /tmp and "
                                                    "/dev/shm get a quarter each"),
    video: bool = typer.Option(True, help="upload a short top-down video of the first validation episode"),
    keep_work: bool = typer.Option(False, help="keep each job's folder after its result is uploaded"),
    robot_cmd: str | None = typer.Option(None, help="robot node (robot protocol) that target jobs run on "
                                                    "[the reality model]"),
    robot_options: RobotNodeOptions = None,  # the --robot-* options: with_robot_node_options
    autolab: Path | None = typer.Option(None, "--autolab", help="lab.yaml: also lease Autolab jobs (feature autolab) "
                                        "and run them on this lab's robots, one job per free robot at once, "
                                        "measured by its watchtowers (docs/autolab.md)"),
) -> None:
    """Pull jobs from a challenges server and evaluate them, until stopped (SIGTERM / Ctrl-C).

    Agent packages run as an unprivileged user (--agent-user) in bubblewrap: no network, no other
    processes, a read-only view of their package and the runtime, bounded scratch space, CPU / memory /
    file-size / process limits. The evaluator must run as root to switch to that user; see
    `proxybench sandbox check`. Target jobs run on the reality model (a simulated stand-in for a real
    robot), or on the robot node of --robot-cmd, after a compliance check. Many evaluators, on many
    machines, can pull from one server.
    """
    require_extra("server", ("httpx",))
    from rich.logging import RichHandler

    from proxybench.cli.server import read_token

    secret = read_token(token, token_file)

    from proxybench.client import ServerError
    from proxybench.evaluator import Evaluator, EvaluatorConfig, Limits

    feats = tuple(dict.fromkeys(f.strip() for f in features.split(",") if f.strip()))
    lab = None
    if autolab is not None:
        from proxybench.autolab.lab import LabError, check_lab, load_lab

        try:
            lab = load_lab(autolab)
            check_lab(lab, str(autolab))
        except LabError as exc:
            raise fail(exc, 2, mark="✗") from None
        feats = (*feats, "autolab") if "autolab" not in feats else feats
    if not feats:
        raise typer.BadParameter("give at least one feature (sim, target)", param_hint="--features")
    unknown = [f for f in feats if f not in KNOWN_FEATURES and not (f == "autolab" and lab is not None)]
    if unknown:
        err_console.print(f"[yellow]![/yellow] feature(s) {', '.join(unknown)} are not known to this evaluator "
                          f"({', '.join(KNOWN_FEATURES)}); jobs needing them will end in host-error")
    if robot_cmd and "target" not in feats:
        err_console.print("[yellow]![/yellow] --robot-cmd is used for target jobs only; add 'target' to --features")
    name = name or socket.gethostname()
    logging.basicConfig(level=logging.WARNING, handlers=[RichHandler(console=err_console, show_path=False)],
                        format="%(message)s")
    from proxybench.evaluator.workdir import WorkDirError, default_work_dir

    try:
        work_dir = work_dir or default_work_dir(name)
    except WorkDirError as exc:
        raise typer.BadParameter(str(exc), param_hint="--name") from None
    config = EvaluatorConfig(
        name=name, features=feats, poll=poll, agent_user=agent_user, dev_unsafe=dev_unsafe_same_user,
        work_dir=work_dir,
        limits=Limits(cpu_seconds=cpu_seconds, memory_bytes=memory_mb << 20, file_bytes=file_mb << 20,
                      scratch_bytes=scratch_mb << 20, tmp_bytes=max(1, scratch_mb // 4) << 20),
        video=video, keep_work=keep_work, robot_cmd=robot_cmd, robot_options=robot_options.non_default(),
        autolab=lab)
    try:
        ev = Evaluator(server or "http://127.0.0.1:8000", secret, config, _reporter())
    except RuntimeError as exc:
        raise fail(exc, 2, mark="✗") from None
    ev.install_signal_handlers()
    try:
        done = ev.run(once=once)
    except ServerError as exc:
        raise fail(exc, 2, mark="✗") from None
    if ev.stop_reason:
        console.print(f"evaluator {name!r} stopped ({ev.stop_reason}) after {done} job(s)")
