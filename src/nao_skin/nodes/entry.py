"""The nodes' console scripts, as ``ros2 run nao_skin <node>`` starts them: each imports its node only
after :func:`~nao_skin.errors.end_at_once_on_ctrl_c`, so a Ctrl-C while rclpy and scipy import is one
line, never a traceback. (``nao-skin record`` starts its nodes in their own sessions, so a terminal's
Ctrl-C never reaches them.)
"""
from __future__ import annotations

import importlib

from nao_skin.errors import end_at_once_on_ctrl_c


def _run(name: str) -> int:
    end_at_once_on_ctrl_c(name)          # the node's own stop handler replaces it once it runs
    return importlib.import_module(f"nao_skin.nodes.{name}").main()


def calibrate() -> int:
    return _run("calibrate")


def naoqi_bridge() -> int:
    return _run("naoqi_bridge")


def yarp_skin_bridge() -> int:
    return _run("yarp_skin_bridge")


def sim_robot() -> int:
    return _run("sim_robot")


def pairing_recorder() -> int:
    return _run("pairing_recorder")


def skin_heatmap() -> int:
    return _run("skin_heatmap")
