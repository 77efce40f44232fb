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
    # libyaml's white space: a tab between tokens (not in an indentation), in and after a plain scalar
    "tabs": f"{NODE}:\t\n  ros__parameters:\n    a:\t1\n    b: 1\t\n    c: [1,\t2]\n    d: x\ty\n    e\t: 'x'\t# c\n"
            f"    f: {{g:\t1}}\n",
    # strtod's underflow (ERANGE) gives the text; an exact subnormal (hexadecimal) is a number
    "underflow": f"{NODE}:\n  ros__parameters:\n    a: 4.9e-324\n    b: 2.2250738585072011e-308\n    c: 0x1p-1074\n"
                 f"    d: 0xap-2000\n    e: 2.2250738585072014e-308\n    f: -1e-310\n    g: 0x1.8p-1074\n",
    "yaml_1_1": f"%YAML 1.1\n---\n{NODE}:\n  ros__parameters:\n    a: 1\n",
    "scalar_documents": f"{NODE}:\n  ros__parameters:\n    a: [1]\n---\n5\n",
    "document_start": f"---\n{NODE}:\n  ros__parameters:\n    a: 1\n...\n",
    "node_names": f"ns/{NODE}:\n  ros__parameters:\n    a: 1\n/ns/:\n  {NODE}:\n    ros__parameters:\n      b: 1\n"
                  f"/x__y/_z/**/*:\n  ros__parameters:\n    c: 1\n/{'n' * 244}/{'c' * 255}:\n  ros__parameters:\n    d: 1\n",
    "parameters_key_start": f"{NODE}:\n  ros__parametersX:\n    a: 1\n",
    # what rcl refuses
    "yaml_1_2": f"%YAML 1.2\n---\n{NODE}:\n  ros__parameters:\n    a: 1\n",
    "empty_document_after": f"{NODE}:\n  ros__parameters:\n    a: 1\n---\n",
    "only_document_start": "---\n",
    "two_scalar_documents": "5\n---\n5\n",
    "mapping_after_a_scalar_document": f"~\n---\n{NODE}:\n  ros__parameters:\n    a: 1\n",
    "colon_in_flow": f"{NODE}:\n  ros__parameters:\n    a: [http://host]\n",
    "empty_name": f"{NODE}:\n  ros__parameters:\n    '': 1\n",
    "empty_node_name": "'':\n  ros__parameters:\n    a: 1\n",
    "alias_as_key": f"{NODE}:\n  ros__parameters:\n    &k a: 1\n    *k : 2\n",
    "node_name_digit": "1node:\n  ros__parameters:\n    a: 1\n",
    "node_name_dash": "a-b:\n  ros__parameters:\n    a: 1\n",
    "node_name_dot": "my.node:\n  ros__parameters:\n    a: 1\n",
    "node_name_slash_only": "/:\n  ros__parameters:\n    a: 1\n",
    "node_name_double_slash": f"//{NODE}:\n  ros__parameters:\n    a: 1\n",
    "node_name_trailing_slash": f"/ns/:\n  ros__parameters:\n    a: 1\n",
    "nested_node_name_from_root": f"/ns:\n  /{NODE}:\n    ros__parameters:\n      a: 1\n",
    "node_name_part_wildcard": "/cal*:\n  ros__parameters:\n    a: 1\n",
    "node_name_too_long": f"{'c' * 256}:\n  ros__parameters:\n    a: 1\n",
    "namespace_too_long": f"/{'n' * 245}/{NODE}:\n  ros__parameters:\n    a: 1\n",
    "no_node_name": "ros__parameters:\n  a: 1\n",
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
