"""Rendering of the Gymnasium envs in Gymnasium's standard modes, and what a frame shows.

Modes (``metadata["render_modes"]``), as Gymnasium defines them:

- ``"rgb_array"``: ``render()`` returns the current frame, ``(H, W, 3)`` uint8;
- ``"human"``: the frame is shown in a window at every ``reset`` and ``step`` (real time, at
  ``metadata["render_fps"]``) and ``render()`` returns None. The window needs a screen (an interactive
  matplotlib backend); where there is none (a server, CI) the env warns once and runs without showing
  anything, so that a training script started over SSH is not lost to a missing display;
- ``"rgb_array_list"``: through ``gymnasium.make``, which wraps ``"rgb_array"`` in ``RenderCollection``.

What a frame shows is ``render_view``: ``"camera"`` (the robot's camera, default), ``"top_down"`` (the
map from above with the robot, NPCs and objects) or ``"both"`` side by side, as in proxybench's videos.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np

from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down

__all__ = ["NO_SCREEN", "RENDER_MODES", "RENDER_VIEWS", "EnvView", "HumanWindow", "check_render_args", "has_screen"]

RENDER_MODES = ["rgb_array", "human"]
RENDER_VIEWS = ("camera", "top_down", "both")
#: matplotlib's backends that draw to files only (what it picks on a machine without a screen)
_FILE_BACKENDS = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template"}


def check_render_args(render_mode: str | None, render_view: str, modes: list[str] = RENDER_MODES) -> None:
    """Refuse a mode or view the env does not have, naming the ones it has."""
    if render_mode is not None and render_mode not in modes:
        hint = " (a view now: render_mode='rgb_array', render_view='top_down')" if render_mode == "top_down" else ""
        raise ValueError(f"render_mode must be one of {modes}, got {render_mode!r}{hint}")
    if render_view not in RENDER_VIEWS:
        raise ValueError(f"render_view must be one of {RENDER_VIEWS}, got {render_view!r}")


def has_screen() -> bool:
    """Whether matplotlib can open a window here (an interactive backend; headless machines get Agg)."""
    import matplotlib

    return matplotlib.get_backend().lower() not in _FILE_BACKENDS


def view_frame(sim: Simulator, i: int, view: str, camera: np.ndarray | None = None) -> np.ndarray:
    """Robot ``i``'s frame in ``view``; ``camera`` is its camera frame when the caller already has it."""
    if view != "top_down" and camera is None:
        sim.enable_rendering()  # state observations: render the camera on demand
        camera = sim.render()[i]
    if view == "camera":
        return camera.copy()
    objects, npcs = sim.world_view(i)
    top = top_down(sim.map, sim.state[i:i + 1, :3], params=sim.params[i], objects=objects, npc_poses=npcs)
    if view == "top_down":
        return top
    from proxybench.media import side_by_side

    return side_by_side(camera, top)


NO_SCREEN = ("render_mode='human' shows nothing here: matplotlib found no screen (no interactive backend, e.g. "
             "no DISPLAY). Use render_mode='rgb_array' and save the frames, or gymnasium.wrappers.RecordVideo")


class HumanWindow:
    """A matplotlib window showing frames at (at most) ``fps`` frames per second."""

    def __init__(self, title: str, fps: float):
        import matplotlib.pyplot as plt

        self._plt = plt
        self.fig, self.ax = plt.subplots(num=title)
        self.ax.set_axis_off()
        self.image: Any = None
        self.dt = 1.0 / fps
        self._last = 0.0

    def show(self, frame: np.ndarray) -> None:
        if self.image is None:
            self.image = self.ax.imshow(frame)
            self.fig.tight_layout()
        else:
            self.image.set_data(frame)
        wait = self.dt - (time.monotonic() - self._last)
        self._plt.pause(max(wait, 1e-3))  # draws and keeps the window responsive
        self._last = time.monotonic()

    def close(self) -> None:
        self._plt.close(self.fig)


class EnvView:
    """The render state of a single env: its mode, view and (in human mode) its window."""

    def __init__(self, render_mode: str | None, render_view: str, fps: float, title: str = "proxybench"):
        check_render_args(render_mode, render_view)
        self.mode, self.view, self.fps, self.title = render_mode, render_view, fps, title
        self.window: HumanWindow | None = None
        self.headless = False  # human mode without a screen: warned once, shows nothing

    def render(self, sim: Simulator, camera: np.ndarray | None) -> np.ndarray | None:
        """What ``Env.render()`` returns: the frame in ``rgb_array`` mode, else None."""
        if self.mode == "rgb_array":
            return view_frame(sim, 0, self.view, camera)
        return None

    def after_update(self, sim: Simulator, camera: np.ndarray | None) -> None:
        """Called at the end of ``reset`` and ``step``: human mode shows the new frame."""
        if self.mode != "human" or self.headless:
            return
        if self.window is None:
            if not has_screen():
                self.headless = True
                gym.logger.warn(NO_SCREEN)
                return
            self.window = HumanWindow(self.title, self.fps)
        self.window.show(view_frame(sim, 0, self.view, camera))

    def close(self) -> None:
        if self.window is not None:
            self.window.close()
            self.window = None
