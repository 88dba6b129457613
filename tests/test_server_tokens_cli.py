"""Tokens as a user handles them: never on a command line, from the environment or a file; listed, made and
revoked with ``proxybench server token-*``; a revoked token is refused at once (the CLI, the API)."""

from __future__ import annotations

import os
import re

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.server.app import create_app
from proxybench.server.config import Settings
from proxybench.server.web.demo import serve_in_thread

runner = CliRunner()


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """(server URL, admin token, a developer's token) of a server in a thread."""
    app_ = create_app(Settings(data_dir=tmp_path_factory.mktemp("tokens") / "data"))
    with TestClient(app_) as c:
        dev = c.post("/api/v1/users", headers={"Authorization": f"Bearer {app_.state.admin_token}"},
                     json={"name": "dev", "role": "developer"}).json()["token"]
    with serve_in_thread(app_) as url:
        yield url, app_.state.admin_token, dev


def cli(*args: str, env: dict[str, str] | None = None):
    clean = {k: None for k in ("PROXYBENCH_TOKEN", "PROXYBENCH_TOKEN_FILE")}
    return runner.invoke(app, list(args), env={**clean, **(env or {})})


def test_a_token_on_the_command_line_is_refused_everywhere(live, tmp_path):
    url, admin, _ = live
    for args in (["leaderboard", "aido_lf"], ["submit", "vision", "--benchmark", "aido_lf"],
                 ["server", "user-add", "zed"], ["server", "token-list"], ["evaluator", "--once"]):
        res = cli(*args, "--server", url, "--token", admin)
        assert res.exit_code == 2, (args, res.output)
        assert "/proc/PID/cmdline" in res.output and "PROXYBENCH_TOKEN" in res.output, res.output


def test_tokens_from_the_environment_or_a_file(live, tmp_path):
    url, _, dev = live
    res = cli("leaderboard", "aido_lf", "--server", url, env={"PROXYBENCH_TOKEN": dev})
    assert res.exit_code == 0, res.output
    f = tmp_path / "dev.token"
    f.write_text(dev + "\n")
    os.chmod(f, 0o600)
    assert cli("leaderboard", "aido_lf", "--server", url, "--token-file", str(f)).exit_code == 0
    assert cli("leaderboard", "aido_lf", "--server", url, env={"PROXYBENCH_TOKEN_FILE": str(f)}).exit_code == 0
    os.chmod(f, 0o644)
    res = cli("leaderboard", "aido_lf", "--server", url, "--token-file", str(f))
    assert res.exit_code == 0 and "other users can read it" in res.output
    res = cli("leaderboard", "aido_lf", "--server", url, "--token-file", str(tmp_path / "missing"))
    assert res.exit_code == 2 and "missing" in res.output and "PROXYBENCH_TOKEN" in res.output


def test_list_add_and_revoke_tokens(live, tmp_path):
    url, admin, dev = live
    env = {"PROXYBENCH_TOKEN": dev}
    out = tmp_path / "laptop.token"
    res = cli("server", "token-add", "--label", "laptop", "--out", str(out), "--server", url, env=env)
    assert res.exit_code == 0, res.output
    laptop = out.read_text().strip()
    assert laptop.startswith("pbt_") and laptop not in res.output and (out.stat().st_mode & 0o077) == 0
    res = cli("server", "token-list", "--server", url, env=env)
    assert res.exit_code == 0 and "laptop" in res.output and laptop not in res.output
    token_id = re.search(r"│ (\d+)\s+│ dev\s+│ " + re.escape(laptop[:10]), res.output).group(1)
    assert cli("leaderboard", "aido_lf", "--server", url, env={"PROXYBENCH_TOKEN": laptop}).exit_code == 0
    res = cli("server", "token-revoke", token_id, "--server", url, env=env)
    assert res.exit_code == 0 and "revoked" in res.output
    res = cli("leaderboard", "aido_lf", "--server", url, env={"PROXYBENCH_TOKEN": laptop})
    assert res.exit_code == 1 and "revoked" in res.output
    # another developer cannot revoke yours; a super-user can list and revoke anyone's
    other = cli("server", "user-add", "other", "--server", url, env={"PROXYBENCH_TOKEN": admin})
    other_token = re.search(r"(pbt_\S+)", other.output).group(1)
    res = cli("server", "token-list", "--user", "dev", "--server", url, env={"PROXYBENCH_TOKEN": admin})
    assert res.exit_code == 0 and "laptop" in res.output
    first_id = re.search(r"│ (\d+)\s+│ dev\s+│ " + re.escape(dev[:10]), res.output).group(1)
    res = cli("server", "token-revoke", first_id, "--server", url, env={"PROXYBENCH_TOKEN": other_token})
    assert res.exit_code == 1 and "another user" in res.output
    assert cli("leaderboard", "aido_lf", "--server", url, env=env).exit_code == 0
