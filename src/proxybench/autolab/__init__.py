"""The Autolab's eyes: watchtowers, AprilTags and a pose graph turn a lab's image logs into a recorded target.

Modules: ``watchtowers`` (layout files, generated layouts), ``calibration`` (a watchtower's calibration file),
``geometry`` (frames), ``detect`` (tags and their camera-relative poses), ``posegraph`` (the graph and its
solvers), ``localize`` (logs → trajectories in the map frame), ``logs`` (image folders and ROS bags),
``validate`` (the DTA's validation phase), ``effect`` (what localisation does to metrics and PRPV).
See docs/autolab.md.
"""
