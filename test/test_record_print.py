"""``nao-skin record --print``: the command lines of the record session it starts (the launch file starts the same
session description: test_launch.py compares the parameters of the nodes it runs with it)."""
import shlex
import sys


def test_record_print_shows_these_command_lines(tmp_path):
    import subprocess

    bag = tmp_path / "b"
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(bag)],
                         capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert run.returncode == 0, run.stderr
    printed = {line.split(": ", 1)[0]: shlex.split(line.split(": ", 1)[1]) for line in run.stdout.splitlines()
               if ": " in line}
    assert {"sim_robot", "pairing_recorder", "skin_heatmap", "calibrate"} <= set(printed)
    assert f"bag_path:={bag}" in printed["pairing_recorder"]


def test_record_print_puts_every_node_in_the_namespace(tmp_path):
    import subprocess

    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(tmp_path / "b"),
                          "--namespace", "nao2/"], capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert run.returncode == 0, run.stderr
    lines = [line for line in run.stdout.splitlines() if ": " in line]
    assert lines and all("-r __ns:=/nao2" in line for line in lines), run.stdout
    bad = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(tmp_path / "b"),
                          "--namespace", "/2nao"], capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "--namespace /2nao: expected a ROS namespace such as /nao2" in bad.stderr, bad.stderr


def test_record_takes_a_parameters_file_and_a_seed_as_the_launch_file_does(tmp_path):
    """--params-file FILE (record.launch.py's params_file:=) goes to every node after the package's own files,
    the session's overrides after it; --seed N to the simulated robot and, kept in the bag, to the recorder."""
    import subprocess

    mine = tmp_path / "mine.yaml"
    mine.write_text("calibrate:\n  ros__parameters:\n    gate_mm: 20\n")
    run = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(tmp_path / "b"),
                          "--params-file", str(mine), "--seed", "7"], capture_output=True, text=True, timeout=60,
                         cwd=str(tmp_path))
    assert run.returncode == 0, run.stderr
    printed = {line.split(": ", 1)[0]: shlex.split(line.split(": ", 1)[1]) for line in run.stdout.splitlines()
               if ": " in line}
    for name in ("sim_robot", "pairing_recorder", "skin_heatmap", "calibrate"):
        files = [argv for i, argv in enumerate(printed[name]) if printed[name][i - 1] == "--params-file"]
        assert files[-1] == str(mine) and files[0].endswith("record.yaml"), printed[name]
    assert "seed:=7" in printed["sim_robot"] and "sim_seed:=7" in printed["pairing_recorder"]
    mine.write_text("calibrate:\n  ros__parameters:\n    gate_mm: far\n")
    bad = subprocess.run([sys.executable, "-m", "nao_skin.cli", "record", "--print", "--bag", str(tmp_path / "b"),
                          "--params-file", str(mine)], capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert f"--params-file {mine}: calibrate.gate_mm=far: expected a number like 15.0" in bad.stderr, bad.stderr
