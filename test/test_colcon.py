"""The package in a real colcon workspace: ``colcon build`` installs what ``ros2 run``/``ros2 launch`` need,
and the installed ``calibrate`` node calibrates the installed bundled recording.

The repo is copied to ``ws/src/nao_skin`` of a temporary workspace and built with the venv's colcon
(colcon-ros' ament_python build: setuptools' ``install`` with setup.cfg's ``install_scripts``); the node
then runs from the install tree in the environment ``source install/setup.bash`` gives, from a directory
outside both trees, so neither its code nor its config can come from the checkout.
"""
from __future__ import annotations

import ast
import importlib.metadata
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from ros_harness import ROOT, unique_domain_id

COLCON = Path(sys.executable).with_name("colcon")
NODES = ("calibrate", "naoqi_bridge", "yarp_skin_bridge", "sim_robot", "pairing_recorder", "skin_heatmap")
DATA_DIRS = ("launch", "config", "urdf", "bags")
# not part of the package: the venv, VCS, colcon/cmake artefacts, outputs, caches
TOP_LEVEL_SKIPPED = {".venv", ".git", "out", "build", "install", "log"}
CALIBRATION_WAIT_S = 300.0      # ~4000 touches take 5-40 s on a 2-core machine; the poll ends at the first sign


def _ignore(top: str):
    def ignore(directory: str, names: list) -> list:
        skipped = [n for n in names if n in ("__pycache__", ".pytest_cache", ".import_linter_cache")
                   or n.endswith(".egg-info")]
        if os.path.samefile(directory, top):
            skipped += [n for n in names if n in TOP_LEVEL_SKIPPED]
        return skipped
    return ignore


def _package_files(src: Path, sub: str) -> list:
    """Files under ``src/sub`` setup.py's ``files()`` installs (it skips dotfiles and .gitkeep)."""
    return sorted(p.relative_to(src) for p in (src / sub).rglob("*")
                  if p.is_file() and not p.name.startswith(".") and "__pycache__" not in p.parts)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with the package copied in and built: (ws, source copy, install prefix)."""
    ws = tmp_path_factory.mktemp("colcon") / "ws"
    src = ws / "src" / "nao_skin"
    shutil.copytree(ROOT, src, ignore=_ignore(str(ROOT)), symlinks=True)
    env = dict(os.environ)
    env["COLCON_HOME"] = str(ws.parent / "colcon_home")   # no user defaults.yaml changes the build
    for var in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "PYTHONPATH"):
        env.pop(var, None)
    build = subprocess.run([str(COLCON), "build", "--event-handlers", "console_direct+"], cwd=ws, env=env,
                           capture_output=True, text=True, timeout=900)
    assert build.returncode == 0, (build.stdout[-4000:], build.stderr[-4000:])
    return ws, src, ws / "install" / "nao_skin"


def _site_packages(prefix: Path) -> Path:
    # colcon ran setup.py with this interpreter, so the install uses its version
    return prefix / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages"


def _sourced_env(ws: Path, domain_id: int) -> dict:
    """The environment of a fresh shell after ``source install/setup.bash``, on its own localhost DDS domain."""
    base = dict(os.environ)
    for var in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "PYTHONPATH", "ROS_STATIC_PEERS"):
        base.pop(var, None)
    dump = subprocess.run(["bash", "-c", 'source "$1/install/setup.bash" && env -0', "bash", str(ws)],
                          env=base, capture_output=True, timeout=60)
    assert dump.returncode == 0, dump.stderr.decode(errors="replace")
    env = dict(item.split("=", 1) for item in dump.stdout.decode().split("\0") if "=" in item)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               RMW_IMPLEMENTATION="rmw_fastrtps_cpp", PYTHONUNBUFFERED="1")
    return env


@pytest.mark.slow   # a colcon build
def test_colcon_build_installs_the_nodes_the_data_and_the_ament_index_marker(workspace):
    ws, src, prefix = workspace
    share = prefix / "share" / "nao_skin"
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "nao_skin").is_file()
    assert (share / "package.xml").read_bytes() == (src / "package.xml").read_bytes()

    # every console script setuptools installed (its entry_points.txt) is an executable in lib/nao_skin,
    # where `ros2 run nao_skin <name>` looks; the nodes are among them
    dists = [d for d in importlib.metadata.distributions(path=[str(_site_packages(prefix))])
             if d.metadata["Name"].replace("-", "_") == "nao_skin"]
    assert len(dists) == 1, [d.metadata["Name"] for d in dists]
    scripts = {ep.name for ep in dists[0].entry_points if ep.group == "console_scripts"}
    assert set(NODES) <= scripts, scripts
    for name in scripts:
        exe = prefix / "lib" / "nao_skin" / name
        assert exe.is_file() and os.access(exe, os.X_OK), exe

    # the data, byte for byte: launch files, config and layouts, URDF, the bundled recording
    for must in ("launch/record.launch.py", "launch/calibrate.launch.py", "config/nao_skin.yaml",
                 "config/layouts/l_hand.txt", "config/layouts/torso.txt", "urdf/nao_skin.urdf.xacro",
                 "bags/sim_default/touches/metadata.yaml", "bags/sim_default/truth_calibration.yaml"):
        assert (src / must).is_file(), f"the test's list is stale: {must} is not in the package"
    for sub in DATA_DIRS:
        files = _package_files(src, sub)
        assert files, sub
        for rel in files:
            assert (share / rel).is_file(), f"{rel} not installed in {share}"
            assert (share / rel).read_bytes() == (src / rel).read_bytes(), rel
    # setup.py's files() skips dotfiles, so bags/sim_default/.nao_skin_output (the simulator's output
    # marker) stays in the source tree: nothing reads it as input, and without it no `--force` of a
    # nao-skin command ever replaces the installed recording.


@pytest.mark.slow         # a colcon build and a calibration of ~4000 touches
@pytest.mark.middleware   # the calibrate node, a ROS 2 node on DDS
def test_the_installed_calibrate_node_calibrates_the_installed_recording(workspace, tmp_path):
    ws, _, prefix = workspace
    share = prefix / "share" / "nao_skin"
    env = _sourced_env(ws, unique_domain_id())
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(_site_packages(prefix)), env["PYTHONPATH"]
    assert env["AMENT_PREFIX_PATH"].split(os.pathsep)[0] == str(prefix), env["AMENT_PREFIX_PATH"]
    elsewhere = tmp_path / "cwd"          # not in the checkout, not in the workspace
    elsewhere.mkdir()

    # what `ros2 run nao_skin calibrate` finds and what the installed code sees, with the interpreter
    # the installed script names on its #! line
    exe = prefix / "lib" / "nao_skin" / "calibrate"
    python = exe.read_text().splitlines()[0].removeprefix("#!").strip()
    probe = subprocess.run([python, "-c", (
        "import json, nao_skin, nao_skin.nodes.calibrate as node\n"
        "from nao_skin import paths\n"
        "from ament_index_python.packages import get_package_prefix\n"
        "print(json.dumps({'package': nao_skin.__file__, 'node': node.__file__,"
        " 'prefix': get_package_prefix('nao_skin'),"
        " 'data': str(paths.package_dir()), 'config': str(paths.default_skin_config())}))")],
        cwd=elsewhere, env=env, capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0, probe.stderr
    seen = json.loads(probe.stdout.splitlines()[-1])
    assert Path(seen["package"]).is_relative_to(_site_packages(prefix)), seen
    assert Path(seen["node"]).is_relative_to(_site_packages(prefix)), seen
    assert Path(seen["prefix"]) == prefix, seen
    assert Path(seen["data"]) == share and Path(seen["config"]) == share / "config" / "nao_skin.yaml", seen

    recording = share / "bags" / "sim_default"
    out = tmp_path / "cal"
    argv = [str(exe), "--ros-args", "-p", f"inputs:=['{recording}']", "-p", "calibrate_on_start:=true",
            "-p", f"out_dir:={out}", "-p", "plots:=false"]
    log_out, log_err = tmp_path / "calibrate.out", tmp_path / "calibrate.err"
    with open(log_out, "wb") as fout, open(log_err, "wb") as ferr:
        proc = subprocess.Popen(argv, cwd=elsewhere, env=env, stdout=fout, stderr=ferr, start_new_session=True)
        try:
            # done = both files in place (moved in together) and the node's closing log line written
            deadline = time.monotonic() + CALIBRATION_WAIT_S
            while time.monotonic() < deadline:
                err = log_err.read_text(errors="replace")
                if ((out / "calibration.yaml").is_file() and (out / "report.json").is_file()
                        and "calibrated from 1 input(s)" in err):
                    break
                # a failed calibration ends the node (exit 2): stop at its error line
                assert "[ERROR]" not in err and proc.poll() is None, (proc.poll(), err[-3000:])
                time.sleep(0.2)
            else:
                pytest.fail(f"no calibration after {CALIBRATION_WAIT_S} s: {log_err.read_text()[-3000:]}")
            os.killpg(proc.pid, signal.SIGINT)     # Ctrl-C, as for `ros2 run`
            code = proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
    assert code == 0, log_err.read_text(errors="replace")[-3000:]

    report = json.loads((out / "report.json").read_text())
    assert report["input"]["files"] == [str(recording)], report["input"]
    assert report["input"]["touches_loaded"] > 1000, report["input"]
    assert report["input"]["messages_read"] > report["input"]["touches_loaded"]     # a bag counts its messages
    # the truth beside the installed recording was found, and the calibration moved the skin towards it
    truth_after = report["final"]["truth_taxel_error_mm"]["all"]["median"]
    truth_before = report["before"]["truth_taxel_error_mm"]["all"]["median"]
    assert truth_after < truth_before, (truth_before, truth_after)
    calibration = yaml.safe_load((out / "calibration.yaml").read_text())
    assert set(calibration["parts"]) == {"r_hand", "l_hand", "torso", "head"}, calibration["parts"].keys()
    assert sorted(p.name for p in (out / "taxels").iterdir()) == ["head.txt", "l_hand.txt", "r_hand.txt", "torso.txt"]


# Python modules src/ and launch/ import that are not ROS packages: their rosdep keys, or None for the
# pip-only ones package.xml names in a comment (no rosdep key)
NOT_ROS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
           "matplotlib": "python3-matplotlib", "rosbags": "python3-rosbags-pip", "threadpoolctl": "python3-threadpoolctl",
           "qi": None, "yarp": None}


def _imported_top_level_modules(paths) -> set:
    found = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                found.add(node.module.split(".")[0])
    return found - set(sys.stdlib_module_names) - {"nao_skin"}


def test_package_xml_declares_every_package_the_code_imports():
    """rosdep installs only what package.xml names: an undeclared import breaks a fresh ROS 2 install (and a
    package named there that nothing uses is installed for nothing)."""
    from catkin_pkg.package import parse_package

    package = parse_package(str(ROOT / "package.xml"))     # also validates the format
    declared = {d.name for d in package.exec_depends}
    imported = _imported_top_level_modules(list((ROOT / "src").rglob("*.py")) + list((ROOT / "launch").glob("*.py")))
    assert {"rclpy", "launch"} <= imported        # the scan sees the code's imports
    needed = {NOT_ROS.get(name, name) for name in imported} - {None}
    assert needed <= declared, f"not in package.xml's exec_depend: {sorted(needed - declared)}"
    # and nothing else: what the launch file starts, or a package the code imports
    started = {"robot_state_publisher", "rviz2"}
    assert declared - started <= needed, f"in package.xml but never imported: {sorted(declared - started - needed)}"
