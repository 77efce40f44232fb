"""The console scripts: ``nao-skin`` and the nodes as ``ros2 run nao_skin <node>`` starts them (pip puts
them in the venv's bin, colcon in ``lib/nao_skin``). Each installs
:func:`~nao_skin.errors.end_at_once_on_ctrl_c` before it imports anything of its own, so a Ctrl-C while
rclpy and scipy import is one line, never a traceback, and ignores the stop signals once its program has
returned. (``nao-skin record`` starts its nodes in their own sessions, so a terminal's Ctrl-C never
reaches them.)
"""
from __future__ import annotations

import importlib

from nao_skin.errors import run_program


def _run(prog: str, module: str, function: str = "main") -> int:
    # the module imported inside: a Ctrl-C while rclpy and scipy import ends it at once
    return run_program(prog, lambda: getattr(importlib.import_module(module), function)())


def nao_skin() -> int:
    return _run("nao-skin", "nao_skin.cli")


def calibrate() -> int:
    return _run("calibrate", "nao_skin.nodes.calibrate")


def naoqi_bridge() -> int:
    return _run("naoqi_bridge", "nao_skin.nodes.naoqi_bridge")


def yarp_skin_bridge() -> int:
    return _run("yarp_skin_bridge", "nao_skin.nodes.yarp_skin_bridge")


def fingertip_capture() -> int:
    return _run("fingertip_capture", "nao_skin.nodes.fingertip_capture")


def sim_robot() -> int:
    return _run("sim_robot", "nao_skin.nodes.sim_robot")


def pairing_recorder() -> int:
    return _run("pairing_recorder", "nao_skin.nodes.pairing_recorder")


def skin_heatmap() -> int:
    return _run("skin_heatmap", "nao_skin.nodes.skin_heatmap")
