"""`proxybench serve`, `submit`, `leaderboard` and `server …`: the challenges server and its clients.

``proxybench serve --evaluators 1`` is the one-command local network: an SQLite server in a data folder
and an evaluator process pulling its jobs. Clients find the server in ``--server`` / $PROXYBENCH_SERVER
(default http://127.0.0.1:8000) and their token in $PROXYBENCH_TOKEN, ``--token-file`` or
$PROXYBENCH_TOKEN_FILE (default: the local server's ``proxybench-server/admin.token``). There is no
``--token``: a command line is readable by every user of the machine (``/proc/PID/cmdline``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import typer
from rich.markup import escape
from rich.table import Table

from proxybench.cli.app import app, console, err_console, fail, require_extra
from proxybench.cli.help import HelpTyper
from proxybench.cli.node_options import with_robot_node_options
from proxybench.cli.options import positive
from proxybench.cli.progress import status

if TYPE_CHECKING:
    from proxybench.protocol.options import RobotNodeOptions

server_app = HelpTyper(no_args_is_help=True, help="Administer a challenges server (users, benchmarks, paths).")
app.add_typer(server_app, name="server")

T = TypeVar("T")

DEFAULT_DATA = Path("proxybench-server")
ServerOpt = typer.Option(None, "--server", envvar="PROXYBENCH_SERVER", help="server URL [http://127.0.0.1:8000]")
TokenOpt = typer.Option(None, "--token", hidden=True, help="refused: a command line is visible to every user")
TokenFileOpt = typer.Option(None, "--token-file", help="file holding the API token (or $PROXYBENCH_TOKEN, "
                                                       "$PROXYBENCH_TOKEN_FILE) [proxybench-server/admin.token]")
NO_ARGV_TOKEN = ("--token is not accepted: a command line is readable by every user of the machine "
                 "(/proc/PID/cmdline). Put the token in $PROXYBENCH_TOKEN, or in a file (chmod 600) "
                 "passed as --token-file FILE or $PROXYBENCH_TOKEN_FILE.")


def read_token(token: str | None, token_file: Path | None, default_file: Path | None = None) -> str:
    """The API token from the environment or a file (never argv); exits with a clear message otherwise."""
    from proxybench.client import TokenError, load_token

    if token is not None:
        raise fail(NO_ARGV_TOKEN, 2, mark="✗")
    try:
        value, where = load_token(token_file, default_file)
    except TokenError as exc:
        raise fail(exc, 2, mark="✗") from None
    if "warning" in where:
        err_console.print(f"[yellow]![/yellow] token file {escape(where)}", highlight=False)
    return value


def _client(server: str | None, token: str | None, token_file: Path | None):
    from proxybench.client import ServerClient

    value = read_token(token, token_file, DEFAULT_DATA / "admin.token")
    return ServerClient(server or "http://127.0.0.1:8000", value, retry_for=10.0)


def _ask(server: str | None, token: str | None, token_file: Path | None, call: Callable[[Any], T]) -> T:
    """``call(client)`` with a client of the server the options name; the server's refusal (or no answer) ends
    the command with its message (exit 1), never a traceback."""
    from proxybench.client import ServerError

    try:
        return call(_client(server, token, token_file))
    except ServerError as exc:
        raise fail(exc, mark="✗") from None


def _evaluator_token(settings) -> Path:
    """The local evaluators' token file (user ``local-evaluator``, created once)."""
    from sqlalchemy import select
    from sqlalchemy.orm import sessionmaker

    from proxybench.server.db import make_engine, migrate, session_scope
    from proxybench.server.models import User
    from proxybench.server.security import create_user, issue_token

    path = settings.data_dir / "evaluator.token"
    if path.is_file():
        return path
    engine = make_engine(settings.url)
    migrate(engine)
    with session_scope(sessionmaker(engine)) as session:
        user = session.scalar(select(User).where(User.name == "local-evaluator"))
        token = issue_token(session, user, "local") if user else create_user(session, "local-evaluator",
                                                                               "evaluator")[1]
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    engine.dispose()
    return path


@app.command()
@with_robot_node_options()
def serve(
    host: str = typer.Option("127.0.0.1", help="address to listen on (0.0.0.0 for remote evaluators)"),
    port: int = typer.Option(8000, min=1, max=65535, help="TCP port"),
    data_dir: Path = typer.Option(DEFAULT_DATA, help="SQLite database, artifacts and tokens"),
    database_url: str | None = typer.Option(None, envvar="PROXYBENCH_SERVER_DATABASE_URL",
                                            help="SQLAlchemy URL, e.g. postgresql+psycopg://u:p@host/db"),
    workers: int | None = typer.Option(None, min=1, max=64, help="server processes sharing the port "
                                       "[the number of cores, at most 4]"),
    evaluators: int = typer.Option(0, min=0, help="local evaluator processes to start beside the server"),
    features: str = typer.Option("sim,target", help="features the local evaluators offer"),
    lease_seconds: float = typer.Option(120.0, callback=positive,
                                        help="a job lease lapses this long after the last heartbeat"),
    robot_cmd: str | None = typer.Option(None, help="robot node (robot protocol) the local evaluators run target "
                                                    "jobs on [the reality model]"),
    robot_options: RobotNodeOptions = None,  # the --robot-* options: with_robot_node_options
) -> None:
    """Run the challenges server (SQLite in --data-dir unless --database-url), optionally with evaluators.

    The local evaluators (--evaluators N) run target jobs on the reality model, or on the robot node of
    --robot-cmd started as the --robot-* options say (each evaluator starts its own node).
    """
    require_extra("server")
    if robot_cmd is not None and not evaluators:
        raise typer.BadParameter("only with --evaluators N (it says where the local evaluators run target jobs; "
                                 "a remote evaluator takes its own --robot-cmd)", param_hint="--robot-cmd")
    import uvicorn

    from proxybench.server import clock
    from proxybench.server.app import create_app, prepare
    from proxybench.server.config import Settings
    from proxybench.server.connections import PROTOCOL, raise_open_files

    raise_open_files()  # before the workers start: they inherit it (each client is a socket)

    if workers is None:
        workers = max(1, min(4, len(os.sched_getaffinity(0))))
    settings = Settings.from_env(data_dir=data_dir, database_url=database_url, lease_seconds=lease_seconds,
                                 workers=workers)
    url = f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{port}"
    if settings.workers == 1:
        application = create_app(settings)
    else:
        prepare(settings)
        _export(settings, clock.anchor())
    console.print(f"proxybench server on [bold]{url}[/bold]  (database: {settings.url.split('@')[-1]}, "
                  f"{settings.workers} worker process{'es' if settings.workers > 1 else ''})")
    console.print(f"  web console: {url}/   API docs: {url}/api/v1/docs")
    console.print(f"  admin token: {settings.data_dir / 'admin.token'}")
    procs = []
    if evaluators:
        token_file = _evaluator_token(settings)
        for i in range(evaluators):
            cmd = evaluator_command(url, token_file, f"local-{i + 1}", features,
                                    settings.data_dir / "evaluator-work" / f"local-{i + 1}", robot_cmd, robot_options)
            env = {k: v for k, v in os.environ.items() if k not in ("PROXYBENCH_TOKEN", "PROXYBENCH_TOKEN_FILE")}
            procs.append(subprocess.Popen(cmd, env=env))
        robot = f"; target jobs on the robot node `{robot_cmd}`" if robot_cmd else ""
        console.print(f"  {evaluators} local evaluator(s) started (features: {features}{escape(robot)})",
                      highlight=False)
    # connections: a deadline for request headers and a cap per address (server/connections.py), idle ones closed
    front = {"host": host, "port": port, "log_level": "warning", "timeout_keep_alive": settings.idle_timeout,
             "http": PROTOCOL}
    try:
        if settings.workers == 1:
            uvicorn.run(application, **front)
        else:
            uvicorn.run("proxybench.server.app:app_from_env", factory=True, workers=settings.workers, **front)
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()


def evaluator_command(url: str, token_file: Path, name: str, features: str, work_dir: Path, robot_cmd: str | None,
                      robot_options=None) -> list[str]:
    """The command line of one local evaluator: the server, its token file, and the robot node with every start-up
    option that differs from the defaults (``robot_options``: a ``RobotNodeOptions``; its cwd is absolute)."""
    from proxybench.cli.node_options import ROBOT_OPTION_NAMES

    cmd = [sys.executable, "-m", "proxybench.cli", "evaluator", "--server", url, "--token-file", str(token_file),
           "--name", name, "--features", features, "--work-dir", str(work_dir)]
    if robot_cmd is None:
        return cmd
    cmd += ["--robot-cmd", robot_cmd]
    for key, value in (robot_options.non_default() if robot_options is not None else {}).items():
        if key == "reflection":
            cmd += [] if value else [ROBOT_OPTION_NAMES[key]]
        elif key == "fifo_dir":
            raise typer.BadParameter("the evaluator takes no FIFO folder for its robot node", param_hint="fifo_dir")
        else:
            cmd += [ROBOT_OPTION_NAMES[key], str(value)]
    return cmd


def _export(settings, anchor: float) -> None:
    """Hand the settings (and the server clock) to worker processes through their environment."""
    from proxybench.server.clock import ANCHOR_ENV
    from proxybench.server.config import _ENV_PREFIX

    for name, value in settings.model_dump().items():
        if value is not None:
            os.environ[_ENV_PREFIX + name.upper()] = str(value)
    os.environ[ANCHOR_ENV] = repr(anchor)


@app.command()
def submit(
    agent: str = typer.Argument(..., help="a built-in agent name, an agent package (.zip / .tar.gz) or a container "
                                          "image (.tar: an OCI archive or a docker save tarball)"),
    benchmark: str | None = typer.Option(None, help="benchmark name on the server"),
    path: str | None = typer.Option(None, "--path", help="benchmark path name on the server (instead of --benchmark)"),
    label: str | None = typer.Option(None, help="submission label [the agent name]; an older one is retired"),
    description: str = typer.Option("", help="free text"),
    wait: bool = typer.Option(False, help="wait until every job has finished, then show the leaderboard"),
    timeout: float = typer.Option(1800.0, callback=positive, help="give up waiting after this many seconds"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Submit an agent to a benchmark (or a benchmark path) on a challenges server."""
    require_extra("server", ("httpx",))
    from proxybench.client import ServerError

    if (benchmark is None) == (path is None):
        raise fail("pass exactly one of --benchmark or --path", mark="✗")
    client = _client(server, token, token_file)
    archive = Path(agent)
    try:
        if archive.suffix in (".zip", ".gz", ".tgz", ".tar") and archive.is_file():
            sub = client.submit_archive(archive, label or archive.stem, benchmark=benchmark, path=path,
                                        description=description)
        else:
            sub = client.submit(agent, label or agent, benchmark=benchmark, path=path, description=description)
        console.print(f"submission [bold]{sub['id']}[/bold] ({sub['label']}): jobs "
                      + ", ".join(f"{j['id']} {j['step']} [{j['status']}]" for j in sub["jobs"]))
        if wait:
            sub = _wait(client, sub["id"], timeout)
            for j in sub["jobs"]:
                console.print(f"  job {j['id']} {j['benchmark']} v{j['benchmark_version']}: {j['status']} "
                              f"{j['message'][:200]}", highlight=False)
            for name in sorted({j["benchmark"] for j in sub["jobs"]}):
                _print_board(_settled_board(client, name))
            if any(j["status"] != "success" for j in sub["jobs"]):
                raise typer.Exit(1)
    except ServerError as exc:
        raise fail(exc, mark="✗") from None


def _wait(client, sid: int, timeout: float) -> dict:
    deadline = time.monotonic() + timeout
    with status("waiting for evaluation…") as spinner:
        while True:
            sub = client.get(f"/submissions/{sid}")
            open_jobs = [j for j in sub["jobs"] if j["status"] in ("queued", "evaluating")]
            if not open_jobs:
                return sub
            if time.monotonic() > deadline:
                raise fail(f"submission {sid}: {len(open_jobs)} job(s) still open after {timeout:g} s", mark="✗")
            spinner.update("waiting for evaluation… " + ", ".join(f"job {j['id']}: {j['status']}" for j in open_jobs))
            time.sleep(1.0)


def _settled_board(client, name: str, limit: int | None = 100, patience: float = 15.0) -> dict:
    """The board once it includes every result (a large board is rebuilt about once a second)."""
    deadline = time.monotonic() + patience
    while True:
        board = client.get(f"/leaderboards/{name}", limit=limit)
        if not board.get("stale") or time.monotonic() > deadline:
            return board
        time.sleep(0.5)


def _print_board(board: dict) -> None:
    shown = len(board["rows"])
    total = board.get("total", shown)
    more = f", rows {board.get('offset', 0) + 1}-{board.get('offset', 0) + shown} of {total}" if shown < total else ""
    table = Table(title=f"{board['benchmark']} v{board['version']} ({board['split']}{more})")
    for col in ("rank", "label", "user", "agent"):
        table.add_column(col)
    for c in board["criteria"]:
        table.add_column(f"{c['metric']} {'↑' if c['higher_is_better'] else '↓'}", justify="right")
    for row in board["rows"]:
        values = [row["scores"].get(c["metric"]) for c in board["criteria"]]
        table.add_row(str(row["rank"]), row["label"], row["user"], str(row["agent"]),
                      *("–" if v is None else f"{v:.3f}" for v in values))
    console.print(table)


@app.command("leaderboard")
def show_leaderboard(
    benchmark: str = typer.Argument(..., help="benchmark name on the server"),
    split: str = typer.Option("public", help="public (validation) or hidden (test; super-users)"),
    limit: int = typer.Option(100, min=1, help="rows to show (the best first)"),
    offset: int = typer.Option(0, min=0, help="rows to skip"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Show a benchmark's leaderboard from a challenges server."""
    require_extra("server", ("httpx",))
    _print_board(_ask(server, token, token_file, lambda c: c.leaderboard(benchmark, split, limit=limit, offset=offset)))


@server_app.command("user-add")
def user_add(
    name: str = typer.Argument(...), role: str = typer.Option("developer", help="superuser, developer or evaluator"),
    daily_limit: int | None = typer.Option(None, min=0, help="submissions per 24 h [server default]"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Create a user (super-user token needed); prints the new user's token once."""
    require_extra("server", ("httpx",))
    body = {"name": name, "role": role, "daily_limit": daily_limit}
    out = _ask(server, token, token_file, lambda c: c.post("/users", body))
    console.print(f"user {out['name']} ({out['role']}) token: [bold]{out['token']}[/bold]")


@server_app.command("benchmark-add")
def benchmark_add(
    file: Path = typer.Argument(..., exists=True, dir_okay=False, help="benchmark YAML"),
    features: str = typer.Option("sim", help="features an evaluator must offer, comma-separated (sim, target)"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Upload a benchmark file (a changed file under a known name becomes a new version)."""
    require_extra("server", ("httpx",))
    from proxybench.untrusted import UntrustedInputError, read_text_file

    try:
        text = read_text_file(file)
    except UntrustedInputError as exc:
        raise fail(exc, mark="✗") from None
    body = {"yaml": text, "features": [f for f in features.split(",") if f]}
    out = _ask(server, token, token_file, lambda c: c.post("/benchmarks", body))
    console.print(f"benchmark {out['name']} v{out['version']} " + ("stored" if out["created"] else "unchanged"))


@server_app.command("path-add")
def path_add(
    file: Path = typer.Argument(..., exists=True, dir_okay=False, help="YAML with name, description, steps, edges"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Define a benchmark path: steps (benchmarks) and edges with conditions to progress."""
    require_extra("server", ("httpx",))
    from proxybench.untrusted import UntrustedInputError, load_yaml_file

    try:
        data = load_yaml_file(file, max_depth=32)
    except UntrustedInputError as exc:
        raise fail(exc, mark="✗") from None
    if not isinstance(data, dict):
        raise fail(f"{file}: expected a mapping with name, steps, edges", mark="✗")
    body = {"name": data.get("name"), "description": data.get("description", ""),
            "spec": {"steps": data.get("steps"), "edges": data.get("edges", [])}}
    out = _ask(server, token, token_file, lambda c: c.post("/paths", body))
    console.print(f"path {out['name']}: {len(out['spec']['steps'])} steps, {len(out['spec']['edges'])} edges")


@server_app.command("token-list")
def token_list(
    user: str | None = typer.Option(None, help="another user's tokens (super-users)"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """List API tokens (yours, or --user's): id, prefix, label, created, revoked. Never their text."""
    require_extra("server", ("httpx",))
    rows = _ask(server, token, token_file, lambda c: c.tokens(user))
    table = Table(title=f"API tokens of {user or 'you'}")
    for col in ("id", "user", "prefix", "label", "created (UTC)", "revoked (UTC)"):
        table.add_column(col)
    for t in rows:
        table.add_row(str(t["id"]), t["user"], t["prefix"] + "…", t["label"], _utc(t["created_at"]),
                      _utc(t["revoked_at"]) if t["revoked"] else "")
    console.print(table)


@server_app.command("token-add")
def token_add(
    label: str = typer.Option("", help="what the token is for, e.g. the machine it lives on"),
    out: Path | None = typer.Option(None, "--out", help="write the token to this file (mode 600) instead of "
                                                      "printing it"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Make another token for yourself (one per machine makes revoking one painless)."""
    require_extra("server", ("httpx",))
    made = _ask(server, token, token_file, lambda c: c.new_token(label))
    if out is not None:
        fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(made["token"] + "\n")
        console.print(f"token {made['id']} ({made['prefix']}…) written to {out}")
    else:
        console.print(f"token {made['id']}: [bold]{made['token']}[/bold]  (shown once)")


@server_app.command("token-revoke")
def token_revoke(
    token_id: int = typer.Argument(..., min=1, help="the token's id (proxybench server token-list)"),
    server: str | None = ServerOpt, token: str | None = TokenOpt, token_file: Path | None = TokenFileOpt,
) -> None:
    """Revoke a token for good (yours; super-users: anyone's); its web sessions end with it."""
    require_extra("server", ("httpx",))
    out = _ask(server, token, token_file, lambda c: c.revoke_token(token_id))
    console.print(f"token {out['id']} of {out['user']} ({out['prefix']}…) revoked")


def _utc(t: float | None) -> str:
    return "" if t is None else time.strftime("%Y-%m-%d %H:%M", time.gmtime(t))
