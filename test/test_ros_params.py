"""Our reading of ROS parameter files against rcl's own: every file rcl takes, we take, with the same values
for the node; every file rcl refuses, we refuse in one line (before rcl's two). rcl is asked here as a node
asks it, ``rclpy.init(args=['--ros-args', '--params-file', F])``, and its verdict is never written down."""
from __future__ import annotations

import math

import pytest
from ros_harness import ros_env, unique_domain_id

rclpy = pytest.importorskip("rclpy")
from rclpy.context import Context  # noqa: E402

from nao_skin.formats.ros_params import ParamsFileError, parameters_for, read_params_file  # noqa: E402

pytestmark = pytest.mark.middleware

NODE = "calibrate"
DOCUMENTS = {
    # what launch_ros writes for a list (a Python tuple), and its other temporary files
    "launch_ros_tuple": "/**:\n  ros__parameters:\n    inputs: !!python/tuple\n    - a.bag\n    - 'b c.bag'\n",
    "launch_ros_flow": "/**:\n  ros__parameters: {inputs: !!python/tuple [x], live: false, out_dir: d}\n",
    "bare_value": "gate_mm 20\n",
    "empty": "",
    "only_comment": "# nothing\n",
    "null_document": "~\n",
    "duplicate_parameter": f"{NODE}:\n  ros__parameters:\n    a: 1\n    a: 2\n",
    "duplicate_node": f"{NODE}:\n  ros__parameters:\n    a: 1\n{NODE}:\n  ros__parameters:\n    b: 2\n",
    "two_documents": f"{NODE}:\n  ros__parameters:\n    a: 1\n---\n{NODE}:\n  ros__parameters:\n    b: x\n",
    "booleans": f"{NODE}:\n  ros__parameters:\n    a: y\n    b: N\n    c: on\n    d: OFF\n    e: 'yes'\n"
                f"    f: True\n    g: no\n",
    "integers": f"{NODE}:\n  ros__parameters:\n    a: 0x1F\n    b: 017\n    c: +5\n    d: -0x10\n    e: 0\n"
                f"    f: 99999999999999999999\n    g: 1_000\n",
    "floats": f"{NODE}:\n  ros__parameters:\n    a: 1e3\n    b: 08\n    c: 1.\n    d: .5\n    e: 0x1p3\n"
              f"    f: -.inf\n    g: .NaN\n    h: inf\n    i: 1e-400\n    j: 1e400\n    k: 1.5e-3\n",
    "strings": f"{NODE}:\n  ros__parameters:\n    a: ~\n    b: null\n    c: '5'\n    d: !!str 5\n"
               f"    e: !!int '7'\n    f: |\n      7\n    g: \"\"\n    h: hello world\n",
    "lists": f"{NODE}:\n  ros__parameters:\n    a: []\n    c: [y, no]\n    d: ['1', x]\n    e: [1.5, .inf]\n",
    "list_in_list": f"{NODE}:\n  ros__parameters:\n    b: [[1], 2]\n",
    "mapping_in_list": f"{NODE}:\n  ros__parameters:\n    a: [{{b: 1}}]\n",
    "nested": f"{NODE}:\n  ros__parameters:\n    part_ids: {{torso: 7, hand: {{left: 1}}}}\n",
    "wildcards": f"/**/{NODE}:\n  ros__parameters:\n    a: 1\n/*:\n  ros__parameters:\n    b: 2\n"
                 f"other:\n  ros__parameters:\n    c: 3\n",
    "namespaced": f"/ns:\n  {NODE}:\n    ros__parameters:\n      a: 1\n/{NODE}:\n  ros__parameters:\n    b: 2\n",
    "later_wins": f"/**:\n  ros__parameters:\n    a: 1\n{NODE}:\n  ros__parameters:\n    a: 2\n",
    # what rcl refuses
    "top_list": "- 1\n- 2\n",
    "value_for_node": "extra_node: 5\n",
    "no_value": f"{NODE}:\n  ros__parameters:\n    a:\n",
    "mixed_list": f"{NODE}:\n  ros__parameters:\n    a: [1, 2.0]\n",
    "alias": f"{NODE}:\n  ros__parameters:\n    a: &x 3\n    b: *x\n",
    "merge_key": f"base: &b\n  a: 1\n{NODE}:\n  ros__parameters:\n    <<: *b\n",
    "parameters_not_a_mapping": f"{NODE}:\n  ros__parameters: 5\n",
    "not_yaml": f"{NODE}: [\n",
}
# rcl takes a list or a mapping in a list, but what it then gives is an accident of its event loop (``b: [[1], 2]`` comes
# out as ``b: [1]`` and a parameter named ``2``): only the verdict is compared
VERDICT_ONLY = {"list_in_list", "mapping_in_list"}


def rcl_reads(path, domain: int):
    """What rcl gives the node from the file, or None where rcl refuses the file."""
    context = Context()
    try:
        rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context, domain_id=domain)
    except rclpy._rclpy_pybind11.RCLError:
        return None
    try:
        node = rclpy.create_node(NODE, context=context)
        try:
            return {name: p.value for name, p in node._parameter_overrides.items()}
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


def ours(path):
    try:
        return parameters_for(read_params_file(path), NODE)
    except ParamsFileError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return None


def same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(map(same, a, b))
    return type(a) is type(b) and a == b


@pytest.mark.parametrize("name", DOCUMENTS)
def test_a_parameter_file_reads_as_rcl_reads_it(tmp_path, name):
    path = tmp_path / f"{name}.yaml"
    path.write_text(DOCUMENTS[name])
    theirs = rcl_reads(path, unique_domain_id())
    mine = ours(path)
    assert (theirs is None) == (mine is None), (theirs, mine)
    if theirs is not None and name not in VERDICT_ONLY:
        assert set(theirs) == set(mine) and all(same(theirs[k], mine[k]) for k in theirs), (theirs, mine)


def test_the_comparison_sees_a_difference(tmp_path):
    """rcl and YAML disagree on these; were our reader plain YAML, the test above would fail."""
    import yaml

    path = tmp_path / "p.yaml"
    path.write_text(DOCUMENTS["booleans"])
    theirs = rcl_reads(path, unique_domain_id())
    plain = yaml.safe_load(DOCUMENTS["booleans"])[NODE]["ros__parameters"]
    assert not all(same(theirs[k], plain[k]) for k in theirs)
    assert ros_env  # the harness is importable: the domain comes from it
