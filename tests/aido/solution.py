#!/usr/bin/env python3
"""A minimal AIDO lane-following agent, written with AIDO's own API (aido_schemas + zuper-nodes).

What an AIDO template's ``solution.py`` looks like, shortened: ``wrap_direct`` serves
``protocol_agent_DB20_timestamps``; each frame the JPEG is decoded with Pillow, the yellow centre line
and the white edge line are found in the lower half of the image, and the robot steers towards the
point between them. It prints to stdout as user code does (harmless over FIFOs, AIDO's transport;
``--quiet`` for pipes) and reads its gains from ``config.yaml`` in its working directory.
"""

import io
import sys

import numpy as np
import yaml
from aido_schemas import (
    RGB,
    Context,
    DB20Commands,
    DB20ObservationsWithTimestamp,
    EpisodeStart,
    GetCommands,
    LEDSCommands,
    PWMCommands,
    protocol_agent_DB20_timestamps,
    wrap_direct,
)
from PIL import Image

QUIET = "--quiet" in sys.argv


def say(text: str) -> None:
    if not QUIET:
        print(f"solution: {text}", flush=True)


class LaneFollower:
    def init(self, context: Context):
        with open("config.yaml") as f:  # relative: the agent must run in its own folder
            config = yaml.safe_load(f)
        self.speed, self.gain = float(config["speed"]), float(config["gain"])
        self.steer = 0.0
        say(f"speed {self.speed}, gain {self.gain}")

    def on_received_seed(self, context: Context, data: int):
        np.random.seed(data)

    def on_received_episode_start(self, context: Context, data: EpisodeStart):
        self.steer = 0.0
        say(f"episode {data.episode_name}")

    def on_received_observations(self, context: Context, data: DB20ObservationsWithTimestamp):
        jpg = data.camera.jpg_data
        if not jpg:
            return
        rgb = np.asarray(Image.open(io.BytesIO(jpg)).convert("RGB"), dtype=np.int16)
        low = rgb[rgb.shape[0] // 2:]
        r, g, b = low[..., 0], low[..., 1], low[..., 2]
        yellow = (r > 120) & (g > 100) & (b < 90) & (r - b > 60)
        white = (r > 150) & (g > 150) & (b > 150)
        cols = np.arange(low.shape[1])[None, :].repeat(low.shape[0], 0)
        width = low.shape[1]
        if yellow.any() and white.any():
            centre = (cols[yellow].mean() + cols[white].mean()) / 2
        elif white.any():
            centre = cols[white].mean() - 0.35 * width
        elif yellow.any():
            centre = cols[yellow].mean() + 0.35 * width
        else:
            centre = width / 2
        self.steer = self.gain * (centre - width / 2) / width

    def on_received_get_commands(self, context: Context, data: GetCommands):
        left = float(np.clip(self.speed + self.steer, -1.0, 1.0))
        right = float(np.clip(self.speed - self.steer, -1.0, 1.0))
        c = RGB(0.0, 0.0, 1.0)
        context.write("commands", DB20Commands(PWMCommands(left, right), LEDSCommands(c, c, c, c, c)))


if __name__ == "__main__":
    wrap_direct(node=LaneFollower(), protocol=protocol_agent_DB20_timestamps, args=[])
