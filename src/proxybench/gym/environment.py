"""gym-duckietown's own environment: ``proxybench gym setup`` / ``proxybench gym check``.

gym-duckietown (PyPI ``duckietown-gym-daffy`` 6.1.34, its last release) needs numpy 1.23 and pyglet 1.5,
which proxybench's environment cannot have, so it gets a virtual environment of its own in a user-cache
folder (``$PROXYBENCH_GYM_VENV``, else ``$XDG_CACHE_HOME/proxybench/gym-duckietown-6.1.34``, else
``~/.cache/...``), installed from the freeze beside this module (``requirements.txt``). It renders with
Mesa's software OpenGL through pyglet's headless EGL mode, which needs four Debian packages (no X server).
Setup is idempotent: a complete environment is left as it is.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from proxybench.venv import (
    Steps,
    VenvStatus,
    cache_folder,
    duration,
    make_venv,
    pip_install,
    requirement_count,
    venv_python,
)

__all__ = ["APT_PACKAGES", "GYM_VERSION", "PYTHON_NEEDED", "GymEnvironment", "GymPythonError", "check_environment",
           "check_python", "default_path", "python_version", "setup_environment"]

GYM_VERSION = "6.1.34"
APT_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libglu1-mesa")
REQUIREMENTS = Path(__file__).with_name("requirements.txt")
#: the interpreters the freeze installs on, [low, high): soupsieve 4.1.3 requires Python >= 3.11.5 (pip stops
#: half-way on Debian 12's own 3.11.2, issue 38), numpy 1.23.5 has wheels up to 3.11 only
PYTHON_NEEDED = ((3, 11, 5), (3, 12, 0))
PYTHON_WHY = "soupsieve 4.1.3 needs 3.11.5 or later, numpy 1.23.5 has no wheels past 3.11"
_STAMP = "proxybench-requirements.txt"  # a copy of the freeze it was installed from: changed pins reinstall
#: what check imports and renders in the environment: versions, then one 32×24 frame headless
_PROBE = """
import importlib.metadata as m, json, pyglet
pyglet.options["headless"] = True
import logging; logging.disable(logging.CRITICAL)
out = {p: m.version(p) for p in ("duckietown-gym-daffy", "numpy", "pyglet")}
from gym_duckietown.simulator import Simulator
env = Simulator(map_name="small_loop", camera_width=32, camera_height=24, domain_rand=False)
out["frame"] = list(env.render_obs().shape)
print(json.dumps(out))
"""


def default_path() -> Path:
    """Where gym's environment lives unless ``--path`` says otherwise."""
    return cache_folder("PROXYBENCH_GYM_VENV", f"gym-duckietown-{GYM_VERSION}")


@dataclass
class GymEnvironment(VenvStatus):
    """What ``check`` found: the folder, its interpreter, the versions it runs, every problem, and the Debian
    packages missing."""

    missing_apt: list[str] = field(default_factory=list)


def missing_apt_packages() -> list[str]:
    """The Debian packages of :data:`APT_PACKAGES` not installed (all of them where dpkg is absent)."""
    if shutil.which("dpkg-query") is None:
        return list(APT_PACKAGES)
    out = subprocess.run(["dpkg-query", "-W", "-f", "${Package} ${db:Status-Status}\n", *APT_PACKAGES],
                         capture_output=True, text=True, check=False).stdout
    installed = {line.split()[0].split(":")[0] for line in out.splitlines() if line.endswith(" installed")}
    return [p for p in APT_PACKAGES if p not in installed]


def apt_command(packages: list[str]) -> str:
    return f"sudo apt-get install -y {' '.join(packages)}"


def check_environment(path: Path | None = None, *, render: bool = True) -> GymEnvironment:
    """Check the environment at ``path`` (default :func:`default_path`): Debian packages, interpreter, pins,
    and (``render``) that gym renders one frame headless."""
    path = Path(path or default_path())
    env = GymEnvironment(path, venv_python(path))
    env.missing_apt = missing_apt_packages()
    if env.missing_apt:
        env.problems.append(f"Debian packages missing: {' '.join(env.missing_apt)} (install: "
                            f"{apt_command(env.missing_apt)})")
    if not env.python.exists():
        env.problems.append(f"no gym-duckietown environment at {path} (run: proxybench gym setup"
                            + (f" --path {path}" if path != default_path() else "") + ")")
        return env
    stamp = path / _STAMP
    if not stamp.is_file():  # the stamp is written last: a setup still running, or one that was interrupted
        env.problems.append(f"{path} is not finished: `proxybench gym setup` has not completed there (still "
                            "running, or interrupted: run it again)")
    elif stamp.read_text() != REQUIREMENTS.read_text():
        env.problems.append(f"{path} was installed from other pins than this proxybench's (another version of "
                            "proxybench; run: proxybench gym setup, which rebuilds it)")
    if render and not env.missing_apt:
        _probe(env)
    return env


def _probe(env: GymEnvironment) -> None:
    import json

    try:
        res = subprocess.run([str(env.python), "-c", _PROBE], capture_output=True, text=True, timeout=300,
                             check=False)
    except subprocess.TimeoutExpired:
        env.problems.append("gym-duckietown did not render a frame within 300 s")
        return
    if res.returncode != 0:
        tail = "\n    ".join(res.stderr.strip().splitlines()[-6:])
        env.problems.append(f"gym-duckietown does not start in {env.path}:\n    {tail}")
        return
    out = json.loads(res.stdout.strip().splitlines()[-1])
    env.versions = {k: v for k, v in out.items() if k != "frame"}
    if out["frame"] != [24, 32, 3]:
        env.problems.append(f"gym-duckietown rendered a frame of shape {out['frame']}, expected [24, 32, 3]")


class GymPythonError(RuntimeError):
    """The interpreter gym's environment would be made with (or was made with) cannot install the pins."""


def python_version(python: Path) -> tuple[int, int, int]:
    """The version of the interpreter ``python`` (this process's own without starting it)."""
    if Path(python) == Path(sys.executable):
        return tuple(sys.version_info[:3])  # type: ignore[return-value]
    out = subprocess.run([str(python), "-c", "import sys; print(*sys.version_info[:3])"], capture_output=True,
                         text=True, timeout=60, check=True).stdout.split()
    return int(out[0]), int(out[1]), int(out[2])


def check_python(version: tuple[int, int, int], python: Path, path: Path, *, made: bool) -> None:
    """:class:`GymPythonError` (one line: what is needed, what ``python`` is, what to do) unless the freeze installs
    on ``version``; ``made``: ``python`` is the environment's own at ``path`` (an earlier run made it), else the
    interpreter that would make it."""
    low, high = PYTHON_NEEDED
    if low <= version < high:
        return
    make = f"`python{low[0]}.{low[1]} -m venv {path}` with such an interpreter (a pyenv or uv Python)"
    whose, fix = ("the environment's interpreter", f"remove {path}, make it again: {make}") if made else \
        ("this interpreter", f"make the environment first: {make}")
    raise GymPythonError(f"gym-duckietown's pinned packages need Python {'.'.join(map(str, low))} or a later "
                         f"{low[0]}.{low[1]} ({PYTHON_WHY}); {whose} {python} is Python {'.'.join(map(str, version))}:"
                         f" {fix}, then run proxybench gym setup again")


def setup_environment(path: Path | None = None, *, say: Callable[[str], None] = print) -> GymEnvironment:
    """Create (or complete) gym's environment at ``path``; install the Debian packages when root, else say
    the command. Idempotent: what is in place is kept, and a run with nothing to do says so and only checks.
    Says each step (``2/4 ...``) with its time, pip's progress, and the total: it takes minutes. An interpreter
    the pins cannot install on is refused before anything starts (:class:`GymPythonError`)."""
    path = Path(path or default_path())
    made = venv_python(path).exists()
    interpreter = venv_python(path) if made else Path(sys.executable)
    check_python(python_version(interpreter), interpreter, path, made=made)
    steps = Steps(4, say)
    missing = missing_apt_packages()
    if not missing:
        steps.in_place(f"Debian packages ({' '.join(APT_PACKAGES)}): in place")
    elif os.geteuid() == 0 and shutil.which("apt-get"):
        with steps.step(f"installing Debian packages: {' '.join(missing)}"):
            for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", *missing]):
                subprocess.run(cmd, check=True, env={**os.environ, "DEBIAN_FRONTEND": "noninteractive"})
    else:
        steps.in_place(f"Debian packages missing; as root run: {apt_command(missing)}")
    python = venv_python(path)
    if python.exists():
        steps.in_place(f"virtual environment: in place at {path}")
    else:
        with steps.step(f"creating the virtual environment at {path}"):
            make_venv(path)
    stamp = path / _STAMP
    wanted = REQUIREMENTS.read_text()
    count = requirement_count(wanted.splitlines())
    if stamp.is_file() and stamp.read_text() == wanted:
        steps.in_place(f"gym-duckietown {GYM_VERSION} and its {count} pinned packages: in place")
    else:
        with steps.step(f"installing {count} packages (gym-duckietown {GYM_VERSION} and its pins; minutes)"):
            pip_install(python, ["-r", str(REQUIREMENTS)], say, expected=count)
            stamp.write_text(wanted)
    with steps.step("checking that gym-duckietown renders a frame", work=False):
        env = check_environment(path)
    if steps.worked:
        say(f"gym setup took {duration(steps.elapsed())}")
    else:
        say(f"nothing to do: gym-duckietown's environment is in place at {path} (checked in "
            f"{duration(steps.elapsed())})")
    return env
