"""Rewrite the generated tables of README.md from the code that defines them.

Every block between ``<!-- generated: KIND NAME -->`` and ``<!-- end generated -->``
is rebuilt:

* ``params NODE``: the node's parameters from the one parameter table,
  ``nao_skin.session.params.NODE_PARAMS`` (default, rule, help), and for the
  nodes that declare parameters per skin part, those of the package's skin;
* ``launch FILE``: the launch file's arguments, read with ``ast`` (the launch
  files import ROS' ``launch`` package, which a bare venv lacks): a module-level
  ``ARGUMENTS = {name: (default, description)}`` dict and every
  ``DeclareLaunchArgument("name", default_value=..., description=...)`` call
  with a literal name;
* ``commands``: every ``nao-skin`` command (``NAME`` and ``HELP`` of each module
  of ``nao_skin.commands``, as ``nao-skin --help`` lists them).

Usage (from the repository root, in the venv)::

    .venv/bin/python docs/generate_tables.py            # rewrite README.md in place
    .venv/bin/python docs/generate_tables.py --check    # exit 1 and name the blocks that differ

``test/test_readme.py`` runs the check, and fails too when a node, a launch
file or a block is missing, so the README's tables stay in step with the code.
"""
from __future__ import annotations

import argparse
import ast
import importlib
import pkgutil
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
LAUNCH_DIR = ROOT / "launch"
END = "<!-- end generated -->"
BLOCK = re.compile(r"<!-- generated: (?P<kind>[a-z]+)(?: (?P<name>[^ ]+))? -->\n(?P<body>.*?)" + re.escape(END),
                   re.S)


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _value(value) -> str:
    """A default as it is written in a parameters file (YAML), in backticks."""
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = value if value else '""'
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join('""' if v == "" else (_value(v).strip("`")) for v in value) + "]"
    elif isinstance(value, float):
        text = repr(value)
    else:
        text = str(value)
    return f"`{text}`"


def _takes(default, rule) -> str:
    if rule is not None:
        return rule.describe()
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, (list, tuple)):
        return "a list of texts"
    if isinstance(default, str):
        return "a text"
    if isinstance(default, int):
        return "a whole number"
    return "a number"


def params_table(node: str) -> str:
    from nao_skin.model.skin import load_skin
    from nao_skin.session.params import NODE_PARAMS, PER_PART_NODES, per_part_params

    if node not in NODE_PARAMS:
        raise KeyError(f"params {node}: no such node in nao_skin.session.params.NODE_PARAMS"
                       f" ({', '.join(sorted(NODE_PARAMS))})")
    rows = ["| parameter | default | takes | what |", "|---|---|---|---|"]
    for name, spec in NODE_PARAMS[node].items():
        default, text = spec[0], spec[1]
        rule = spec[2] if len(spec) > 2 else None
        rows.append(f"| `{name}` | {_value(default)} | {_cell(_takes(default, rule))} | {_cell(text)} |")
    if node in PER_PART_NODES:      # one row per family (part_ids.<part>, ...) for the package's skin parts
        parts = sorted(load_skin().parts)
        families: dict = {}
        for name, spec in per_part_params(node, parts).items():
            family, _, part = name.rpartition(".")
            families.setdefault(family, []).append((part, spec))
        for family, items in families.items():
            part, spec = items[0]
            rule = spec[2] if len(spec) > 2 else None
            defaults = ", ".join(f"{p}: {_value(s[0]).strip('`')}" for p, s in items)
            text = spec[1].replace(f"'{part}'", "the part")
            rows.append(f"| `{family}.<part>` | `{defaults}` | {_cell(_takes(spec[0], rule))} | {_cell(text)} |")
    return "\n".join(rows)


def _literal(node):
    try:
        return ast.literal_eval(node)
    except ValueError:
        return ast.unparse(node)


def launch_arguments(path: Path) -> list:
    """``[(name, default or None, description)]`` of a launch file, in the order it declares them."""
    tree = ast.parse(path.read_text(), str(path))
    found: dict = {}
    for node in tree.body:      # module level: ARGUMENTS = {name: (default, description), ...}
        if (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "ARGUMENTS" for t in node.targets)
                and isinstance(node.value, ast.Dict)):
            for key, value in zip(node.value.keys, node.value.values):
                name = _literal(key)
                item = _literal(value)
                if isinstance(item, (tuple, list)) and len(item) >= 2:
                    found[name] = (item[0], item[1])
                else:
                    found[name] = (item, "")
    for node in ast.walk(tree):  # DeclareLaunchArgument("name", default_value=..., description=...)
        if not (isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None))
                == "DeclareLaunchArgument"):
            continue
        name_node = node.args[0] if node.args else next((k.value for k in node.keywords if k.arg == "name"), None)
        if not isinstance(name_node, ast.Constant):
            continue                # the loop over ARGUMENTS: read above
        keywords = {k.arg: _literal(k.value) for k in node.keywords if k.arg}
        found.setdefault(name_node.value, (keywords.get("default_value"), keywords.get("description", "")))
    return [(name, default, text) for name, (default, text) in found.items()]


def launch_table(file: str) -> str:
    path = LAUNCH_DIR / file
    if not path.is_file():
        raise KeyError(f"launch {file}: no such file in launch/")
    rows = ["| argument | default | what |", "|---|---|---|"]
    for name, default, text in launch_arguments(path):
        shown = "(required)" if default is None else (f"`{default}`" if default != "" else '`""`')
        rows.append(f"| `{name}:=` | {_cell(shown)} | {_cell(text)} |")
    return "\n".join(rows)


def commands_table() -> str:
    from nao_skin import commands

    rows = ["| command | what it does |", "|---|---|"]
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        rows.append(f"| `nao-skin {module.NAME}` | {_cell(module.HELP)} |")
    return "\n".join(rows)


def block(kind: str, name: str | None) -> str:
    if kind == "params" and name:
        return params_table(name)
    if kind == "launch" and name:
        return launch_table(name)
    if kind == "commands":
        return commands_table()
    raise KeyError(f"generated block '{kind} {name}': unknown kind (params NODE, launch FILE, commands)")


def regenerate(text: str) -> str:
    return BLOCK.sub(lambda m: f"<!-- generated: {m['kind']}{' ' + m['name'] if m['name'] else ''} -->\n"
                               f"{block(m['kind'], m['name'])}\n{END}", text)


def missing_blocks(text: str) -> list:
    """What the README has no table of: a node of the parameter table, a launch file."""
    from nao_skin.session.params import NODE_PARAMS

    have = {(m["kind"], m["name"]) for m in BLOCK.finditer(text)}
    want = {("params", n) for n in NODE_PARAMS} | {("launch", p.name) for p in LAUNCH_DIR.glob("*.launch.py")}
    want.add(("commands", None))
    return sorted(f"{k} {n or ''}".strip() for k, n in want - have)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 when README.md differs")
    parser.add_argument("--readme", default=str(README), help="the file to rewrite (default: README.md)")
    args = parser.parse_args(argv)
    path = Path(args.readme)
    text = path.read_text()
    new = regenerate(text)
    missing = missing_blocks(new)
    if missing:
        print(f"{path}: no generated block for: {', '.join(missing)}", file=sys.stderr)
    if args.check:
        if new != text:
            stale = [f"{m['kind']} {m['name'] or ''}".strip() for m, n in zip(BLOCK.finditer(text), BLOCK.finditer(new))
                     if m.group(0) != n.group(0)]
            print(f"{path}: generated tables out of date: {', '.join(stale)}; run docs/generate_tables.py",
                  file=sys.stderr)
        return 1 if (new != text or missing) else 0
    if new != text:
        path.write_text(new)
        print(f"{path}: tables rewritten")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
