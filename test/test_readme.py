"""README.md's generated tables (node parameters, launch arguments, the nao-skin commands) match the code.

``docs/generate_tables.py`` rebuilds every block between ``<!-- generated: ... -->`` and ``<!-- end generated -->``
from ``nao_skin.session.params`` (each node's parameters: default, rule, help), the launch files' argument
declarations (read with ``ast``: no ROS ``launch`` package needed) and the command modules. A parameter or a launch
argument added without rerunning it fails here, naming the block; so does a node or launch file with no block.
"""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_LINES = 400


def _generator():
    spec = importlib.util.spec_from_file_location("generate_tables", ROOT / "docs" / "generate_tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_readme_tables_are_the_ones_the_code_defines():
    gen = _generator()
    text = README.read_text()
    new = gen.regenerate(text)
    stale = [f"{m['kind']} {m['name'] or ''}".strip() for m, n in zip(gen.BLOCK.finditer(text), gen.BLOCK.finditer(new))
             if m.group(0) != n.group(0)]
    assert new == text, f"README.md tables out of date ({', '.join(stale)}): run .venv/bin/python docs/generate_tables.py"
    assert gen.missing_blocks(text) == [], "README.md has no generated table for these: add a marker block"


def test_every_node_and_launch_argument_is_in_the_readme():
    """The generator reads what the code declares (not a copy that could drift): every node's parameters and
    every launch argument, the ones only the launch files' DeclareLaunchArgument calls name too."""
    from nao_skin.session.params import NODE_PARAMS

    gen = _generator()
    text = README.read_text()
    for node, params in NODE_PARAMS.items():
        block = text.split(f"<!-- generated: params {node} -->", 1)[1].split(gen.END, 1)[0]
        assert all(f"| `{name}` |" in block for name in params), node
    for launch in sorted((ROOT / "launch").glob("*.launch.py")):
        arguments = gen.launch_arguments(launch)
        assert arguments, launch.name
        block = text.split(f"<!-- generated: launch {launch.name} -->", 1)[1].split(gen.END, 1)[0]
        assert all(f"| `{name}:=` |" in block for name, _, _ in arguments), launch.name
    names = [name for name, _, _ in gen.launch_arguments(ROOT / "launch" / "calibrate.launch.py")]
    assert names[:3] == ["inputs", "out_dir", "calibration"]
    assert "robot" in [name for name, _, _ in gen.launch_arguments(ROOT / "launch" / "record.launch.py")]


def test_the_generator_reads_a_launch_file_without_ros(tmp_path):
    gen = _generator()
    launch = tmp_path / "x.launch.py"
    launch.write_text('from launch.actions import DeclareLaunchArgument\n'
                      'ARGUMENTS = {"robot": ("sim", "which robot"), "namespace": ("", "a"\n " namespace")}\n'
                      'def generate_launch_description():\n'
                      '    return [DeclareLaunchArgument(n, default_value=d, description=t)\n'
                      '            for n, (d, t) in ARGUMENTS.items()]'
                      ' + [DeclareLaunchArgument("extra", description="no default")]\n')
    assert gen.launch_arguments(launch) == [("robot", "sim", "which robot"), ("namespace", "", "a namespace"),
                                            ("extra", None, "no default")]


def test_readme_stays_short_and_its_links_lead_somewhere():
    import re

    text = README.read_text()
    assert len(text.splitlines()) <= MAX_LINES
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if "://" not in target:
            assert (ROOT / target).exists(), target
