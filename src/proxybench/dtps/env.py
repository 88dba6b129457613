"""The SDK environment: a virtual environment of its own holding duckietown-sdk, dtps-http and duckietown-messages.

dtps-http pins ``pydantic==2.10.6`` exactly, so these packages cannot share proxybench's environment. They
live in a venv in the user's cache folder (``$PROXYBENCH_DTPS_ENV``, else ``$XDG_CACHE_HOME/proxybench/
dtps-env``, else ``~/.cache/proxybench/dtps-env``), made by ``proxybench dtps setup`` and checked by
``proxybench dtps check``. proxybench reaches it only by running its interpreter (the bridge, SDK agents).
duckietown-sdk also needs the system library ``libturbojpeg.so.0`` (Debian: ``libturbojpeg0``), which
setup installs with apt when it runs as root and otherwise names the command to run.
"""

from __future__ import annotations

import ctypes.util
import json
import os
import shutil
import subprocess
from pathlib import Path

from proxybench.venv import PipError, Steps, VenvStatus, cache_folder, duration, make_venv, pip_install
from proxybench.venv import venv_python as _python

__all__ = ["PACKAGES", "DtpsEnvError", "EnvStatus", "check_env", "env_path", "sdk_environ", "sdk_python",
           "setup_env"]

#: the released versions this integration was built and tested against (dtps-http is imported by the SDK
#: without being declared, so it is named here)
PACKAGES = ("duckietown-sdk==0.2.0", "dtps-http==1.6.1", "duckietown-messages==0.0.28")
_MARKER = "proxybench-dtps.json"
_APT = "apt-get install -y libturbojpeg0"
_PROBE = """
import json, importlib.metadata as md
import dtps, dtps_http, duckietown_messages
from duckietown.sdk.robots.duckiebot import DB21J
print(json.dumps({p: md.version(p) for p in ("duckietown-sdk", "dtps-http", "duckietown-messages", "pydantic")}))
"""


class DtpsEnvError(RuntimeError):
    """The SDK environment is missing or broken; the message says how to fix it."""


class EnvStatus(VenvStatus):
    """What ``proxybench dtps check`` reports: where the environment is, what it holds, what is wrong."""


def env_path(path: str | Path | None = None) -> Path:
    """The SDK environment's folder: ``path``, else ``$PROXYBENCH_DTPS_ENV``, else the user's cache folder."""
    return Path(path if path is not None else cache_folder("PROXYBENCH_DTPS_ENV", "dtps-env")).expanduser().resolve()


def sdk_python(path: str | Path | None = None) -> Path:
    """The SDK environment's interpreter; :class:`DtpsEnvError` (naming the fix) when it was never set up."""
    where = env_path(path)
    py = _python(where)
    if not (py.exists() and (where / _MARKER).exists()):
        raise DtpsEnvError(f"the duckietown-sdk environment is not set up at {where}: run `proxybench dtps setup"
                           f"{'' if path is None else f' --path {where}'}`")
    return py


def sdk_environ(python: Path, base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) as an activated SDK environment has it: its ``bin`` first
    on ``PATH`` (a script's own ``python3`` subprocesses get the SDK too) and ``VIRTUAL_ENV`` set; proxybench's
    own ``PYTHONHOME`` / ``PYTHONPATH`` dropped, which would mix the two environments' packages."""
    env = dict(os.environ if base is None else base)
    for key in ("PYTHONHOME", "PYTHONPATH", "__PYVENV_LAUNCHER__"):
        env.pop(key, None)
    env["VIRTUAL_ENV"] = str(python.parent.parent)
    env["PATH"] = str(python.parent) + os.pathsep + env.get("PATH", "/usr/bin:/bin")
    return env


def turbojpeg_found() -> bool:
    """Whether the dynamic linker finds libturbojpeg (what duckietown-sdk's JPEG decoder loads)."""
    return ctypes.util.find_library("turbojpeg") is not None


def _install_turbojpeg() -> str | None:
    """Install libturbojpeg0 with apt as root; None when done, else the problem with the command to run."""
    if turbojpeg_found():
        return None
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        return f"libturbojpeg.so.0 is missing (duckietown-sdk decodes camera frames with it): run `sudo {_APT}`"
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    run = subprocess.run(_APT.split(), capture_output=True, text=True, env=env)
    if run.returncode != 0:  # a fresh machine has no package lists yet
        subprocess.run(["apt-get", "update", "-qq"], capture_output=True, env=env)
        run = subprocess.run(_APT.split(), capture_output=True, text=True, env=env)
    if run.returncode != 0 or not turbojpeg_found():
        tail = (run.stderr or run.stdout).strip().splitlines()[-1:] or ["no output"]
        return f"`{_APT}` failed ({tail[0]}): install libturbojpeg0 and run setup again"
    return None


def setup_env(path: str | Path | None = None, *, say=print) -> EnvStatus:
    """Make (or complete) the SDK environment; idempotent: an environment holding :data:`PACKAGES` is kept, and a
    run with nothing to do says so and only checks. Says each step (``2/4 ...``) with its time, pip's progress
    and the total: a fresh setup takes minutes."""
    where = env_path(path)
    steps = Steps(4, say)
    if turbojpeg_found():
        steps.in_place("libturbojpeg.so.0 (camera frames are JPEG): in place")
        problem = None
    elif os.geteuid() != 0 or shutil.which("apt-get") is None:
        problem = _install_turbojpeg()
        steps.in_place(f"libturbojpeg.so.0 missing: {problem}")
    else:
        with steps.step(f"installing libturbojpeg0: {_APT}"):
            problem = _install_turbojpeg()
    marker = where / _MARKER
    current = json.loads(marker.read_text()).get("packages") if marker.exists() else None
    if _python(where).exists():
        steps.in_place(f"virtual environment: in place at {where}")
    else:
        with steps.step(f"creating the virtual environment at {where}"):
            make_venv(where)
    if current == list(PACKAGES):
        steps.in_place(f"{len(PACKAGES)} packages ({', '.join(PACKAGES)}): in place")
    else:
        with steps.step(f"installing {len(PACKAGES)} packages and their dependencies ({' '.join(PACKAGES)}; "
                        "minutes)"):
            try:
                pip_install(_python(where), PACKAGES, say)
            except PipError as exc:
                raise DtpsEnvError(f"pip could not install {', '.join(PACKAGES)} into {where}:\n"
                                   + "\n".join(exc.tail[-10:])) from None
            marker.write_text(json.dumps({"packages": list(PACKAGES)}) + "\n")
    with steps.step("checking that the SDK imports", work=False):
        status = check_env(where)
    if problem and problem not in status.problems:
        status.problems.insert(0, problem)
    if steps.worked:
        say(f"dtps setup took {duration(steps.elapsed())}")
    else:
        say(f"nothing to do: the SDK environment is in place at {where} (checked in {duration(steps.elapsed())})")
    return status


def check_env(path: str | Path | None = None) -> EnvStatus:
    """What the SDK environment holds and what is wrong with it (each problem names its fix)."""
    where = env_path(path)
    status = EnvStatus(where, _python(where))
    if not status.python.exists():
        status.problems.append(f"no environment at {where}: run `proxybench dtps setup`")
        return status
    if not turbojpeg_found():
        status.problems.append(f"libturbojpeg.so.0 is missing: run `sudo {_APT}` (or `proxybench dtps setup` as root)")
    probe = subprocess.run([str(status.python), "-I", "-c", _PROBE], capture_output=True, text=True, timeout=120)
    if probe.returncode != 0:
        last = (probe.stderr.strip().splitlines() or ["no output"])[-1]
        status.problems.append(f"the environment cannot import the SDK ({last}): run `proxybench dtps setup`")
    else:
        status.versions = json.loads(probe.stdout.strip().splitlines()[-1])
    if not (where / _MARKER).exists():
        status.problems.append("the environment was not made by `proxybench dtps setup`: run it")
    return status
