"""Agents as users name them on the command line or in an experiment file, turned into runner specs.

One string per agent:

- ``pid``: a zoo agent (``proxybench agent list``);
- ``models/bc.pt``: a behaviour-cloning checkpoint (``X.pt`` with ``X.json`` beside it);
- ``my-agent.zip`` (or ``.tar``, ``.tar.gz``, ``.tgz``): an agent package, checked and unpacked, its node
  run in the evaluator's sandbox (own folder, resource limits, no network where the host allows);
- ``NAME=COMMAND``: an agent node started with COMMAND (the AIDO protocol on stdin/stdout), labelled NAME;
- ``NAME=sdk:COMMAND`` (``sdk[lockstep]:``, ``sdk[privileged]:``): a duckietown-sdk program driving a virtual
  DB21J over DTPS (docs/dtps.md);
- ``NAME=image:PATH``: a container image (an OCI layout folder, an OCI archive or a ``docker save`` tarball),
  unpacked once into the image cache and run from its own root file system in the evaluator's sandbox
  (docs/evaluator.md, "Container images").

An experiment file may also give an agent as a benchmark file's mapping (:class:`~proxybench.tasks.agent_entries.
AgentEntry`): ``{name, command, cwd, transport, start_timeout, step_timeout, reflection}`` for a node started
with those options, or ``{name}`` alone for any of the strings above.

The label (zoo name, checkpoint path, package name, NAME) is what results and recorded targets call it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from proxybench.runner.jobs import AgentSpec
from proxybench.tasks.agent_entries import AgentEntry

__all__ = ["AgentArgError", "is_image", "parse_agent", "parse_agents"]

_ARCHIVES = (".zip", ".tar", ".tar.gz", ".tgz")


class AgentArgError(ValueError):
    """An agent argument that names nothing runnable; the message says which and why."""


def _is_archive(text: str) -> bool:
    return text.lower().endswith(_ARCHIVES) and Path(text).is_file()


def _package(path: Path, work_dir: Path) -> AgentSpec:
    """A checked, unpacked agent package, its node started in the evaluator's sandbox (refused without one) with
    the start-up options of its manifest (transport, timeouts, reflection)."""
    import shutil

    from proxybench.evaluator.sandbox import Limits, SandboxError, detect_isolation, package_spec, prepare_agent
    from proxybench.protocol.package import PackageError

    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    folder = (work_dir / "agents" / digest[:16]).resolve()
    try:
        if folder.exists():
            shutil.rmtree(folder)  # unpack afresh: a package run never sees what an earlier run left
        folder.mkdir(parents=True)
        manifest = prepare_agent(data, digest, folder)
        # started by whichever worker runs the episode, so no parent-process check (parent=None)
        return package_spec(manifest, folder, Limits(), detect_isolation(), parent=None)
    except PackageError as exc:
        raise AgentArgError(f"agent package {path}: {exc}") from None
    except SandboxError as exc:
        raise AgentArgError(f"agent package {path}: {exc} (`proxybench sandbox setup` prepares this host; a "
                            "package you trust can also run unconfined as --agent NAME=COMMAND from its unpacked "
                            "folder)") from None


def parse_agent(text: str | AgentEntry, work_dir: str | Path = "out/agents") -> AgentSpec:
    """The runner spec of one agent argument (see the module docstring); ``work_dir`` holds unpacked packages."""
    from proxybench.agents.kinds import find_kind
    from proxybench.agents.zoo import ZOO

    if isinstance(text, AgentEntry):
        if text.is_sdk:
            return AgentSpec.sdk(text.name, text.sdk_line, text.sdk_options())
        if text.is_node:
            return AgentSpec.node(text.name, text.command_line, text.node_options())
        text = text.name
    text = text.strip()
    if not text:
        raise AgentArgError("an agent argument is empty")
    if text in ZOO:
        return AgentSpec(text)
    if _is_archive(text):
        return _package(Path(text), Path(work_dir))
    if find_kind(text) is not None:
        return AgentSpec(text)
    name, sep, command = text.partition("=")
    if sep and name.strip() and command.strip() and " " not in name.strip():
        return _node_or_sdk(name.strip(), command.strip())
    hint = ""
    if text.endswith(".pt"):
        hint = " (a checkpoint needs X.pt with X.json beside it)"
    elif text.lower().endswith(_ARCHIVES):
        hint = " (no such package file)"
    raise AgentArgError(f"agent {text!r} is not a zoo agent, a checkpoint, an agent package, NAME=COMMAND or "
                        f"NAME=image:PATH{hint}; "
                        f"zoo agents: {', '.join(ZOO)}")


IMAGE_PREFIX = "image:"


def is_image(text: str) -> bool:
    """Whether an agent argument names a container image (``NAME=image:PATH``)."""
    return text.partition("=")[2].strip().startswith(IMAGE_PREFIX)


def _image(name: str, path: str) -> AgentSpec:
    """A container image, unpacked in the image cache, its node run from its own root file system in the sandbox."""
    from proxybench.evaluator.image_agent import image_spec
    from proxybench.evaluator.images import ImageError
    from proxybench.evaluator.sandbox import SandboxError, detect_isolation

    try:
        # started by whichever worker runs the episode, so no parent-process check (parent=None)
        return image_spec(name, Path(path).expanduser(), detect_isolation(), parent=None)
    except ImageError as exc:
        raise AgentArgError(f"agent {name!r}: {exc}") from None
    except SandboxError as exc:
        raise AgentArgError(f"agent {name!r}: image {path}: {exc} (`proxybench sandbox check` says what this host "
                            "lacks)") from None


def _node_or_sdk(name: str, command: str) -> AgentSpec:
    """``NAME=COMMAND`` (an AIDO node), ``NAME=sdk[...]:COMMAND`` (an SDK program) or ``NAME=image:PATH``."""
    from proxybench.dtps.options import SdkOptions, parse_sdk

    if command.startswith(IMAGE_PREFIX):
        return _image(name, command.removeprefix(IMAGE_PREFIX).strip())

    try:
        sdk = parse_sdk(command)
    except ValueError as exc:
        raise AgentArgError(f"agent {name!r}: {exc}") from None
    if sdk is None:
        return AgentSpec.node(name, command)
    return AgentSpec.sdk(name, sdk[0], SdkOptions(**sdk[1]))


def parse_agents(texts: list[str | AgentEntry] | tuple[str | AgentEntry, ...], work_dir: str | Path = "out/agents",
                 ) -> list[AgentSpec]:
    """Specs of several agent arguments; two with the same label are an error (results are keyed by it)."""
    specs = [parse_agent(t, work_dir) for t in texts]
    seen: set[str] = set()
    for s in specs:
        if s.label in seen:
            raise AgentArgError(f"agent {s.label!r} is given twice")
        seen.add(s.label)
    return specs
