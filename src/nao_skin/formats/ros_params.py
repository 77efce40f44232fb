"""ROS 2 parameter files (``--params-file``), read as rcl reads them.

rcl's parser (rcl_yaml_param_parser) is not a YAML loader: it walks libyaml's events, ignores every tag
but ``!!str`` (launch_ros writes a list as ``!!python/tuple``), types each plain scalar by its text
(``y``/``on``/``off`` are booleans, ``0x1F`` and ``017`` integers, ``null`` and ``~`` strings), merges the
documents of a file and a node name given twice, and refuses aliases, a value where a node name belongs,
a list mixing types, an empty name or document and a node name rmw refuses. Its libyaml takes tabs as white
space where PyYAML refuses them, and refuses ``:`` inside a plain scalar of a flow collection and any ``%YAML``
but 1.1. A check of ours in front of a node must never refuse what rcl accepts, so this
module mirrors those rules; ``test/test_ros_params.py`` compares it with rcl itself on each of them.
"""
from __future__ import annotations

import math
import re
import sys
from fractions import Fraction
from pathlib import Path

from nao_skin.errors import ConfigError
from nao_skin.paths import check_yaml_depth, read_text

PARAMETERS_KEY = "ros__parameters"
_STR_TAG = "tag:yaml.org,2002:str"
_TRUE = {"Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
_FALSE = {"N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}
_YAML_INF_NAN = {".nan": math.nan, ".NaN": math.nan, ".NAN": math.nan}
_YAML_INF_NAN.update({f"{sign}{inf}": (-math.inf if sign == "-" else math.inf)
                      for sign in ("", "+", "-") for inf in (".inf", ".Inf", ".INF")})
# C's strtol(base 0) and strtod, whole text (leading white space skipped, as they do)
_C_INT = re.compile(r"[ \t\n\v\f\r]*[-+]?(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
_C_FLOAT = re.compile(r"[ \t\n\v\f\r]*[-+]?("
                      r"([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?"
                      r"|0[xX]([0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)([pP][-+]?[0-9]+)?"
                      r"|[iI][nN][fF]([iI][nN][iI][tT][yY])?|[nN][aA][nN](\([0-9A-Za-z_]*\))?)")
_INT64 = (-(1 << 63), (1 << 63) - 1)


def _event_tags_loader():
    """A composer that keeps each node's tag as written (None where none was): rcl looks at ``!!str`` only,
    and types every other scalar by its text, not by YAML's resolution."""
    import yaml

    class EventTags(yaml.SafeLoader):
        def resolve(self, kind, value, implicit):
            return None

        # libyaml (rcl's scanner) differs from PyYAML's on white space and on ':' in a flow collection

        def scan_to_next_token(self):
            """libyaml's: a tab is white space between tokens, in a flow collection and after a simple key's ':'
            or a scalar (not where an indentation or a block entry's item begins)."""
            if self.index == 0 and self.peek() == "\ufeff":
                self.forward()
            while True:
                while self.peek() == " " or (self.peek() == "\t" and (self.flow_level or not self.allow_simple_key)):
                    self.forward()
                if self.peek() == "#":
                    while self.peek() not in "\0\r\n\x85\u2028\u2029":
                        self.forward()
                if not self.scan_line_break():
                    return
                if not self.flow_level:
                    self.allow_simple_key = True

        def scan_plain_spaces(self, indent, start_mark):
            """libyaml's: tabs as well as spaces within a line of a plain scalar (``a: x\ty``, ``a: 1\t``)."""
            length = 0
            while self.peek(length) in " \t":
                length += 1
            if length and self.peek(length) not in "\r\n\x85\u2028\u2029":
                whitespaces = self.prefix(length)
                self.forward(length)
                return [whitespaces]
            self.forward(length)
            return super().scan_plain_spaces(indent, start_mark)

        def scan_plain(self):
            """libyaml's: a plain scalar in a flow collection ends at ':', and one going on after it is refused
            (``[x:y]``, ``[http://host]``), where PyYAML takes ``x:y``."""
            token = super().scan_plain()
            if self.flow_level and ":" in token.value:
                raise yaml.scanner.ScannerError("while scanning a plain scalar", token.start_mark,
                                                "found unexpected ':'", token.end_mark)
            return token

        def process_directives(self):
            """libyaml's (rcl's version): ``%YAML 1.1`` only."""
            value = super().process_directives()
            if self.yaml_version not in (None, (1, 1)):
                raise yaml.parser.ParserError(None, None, "found incompatible YAML document (version 1.1 is required)")
            return value

    return EventTags


class ParamsFileError(ConfigError):
    """A parameter file rcl refuses whole (every node that reads it fails to start)."""


def scalar_value(text: str, quoted: bool = False):
    """The value rcl gives a scalar: bool, int (64-bit), float or str, in that order of trial."""
    if quoted:
        return text
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    if _C_INT.fullmatch(text):
        digits = text.strip()
        value = int(digits, 0) if not re.fullmatch(r"[-+]?0[0-7]+", digits) else int(digits, 8)
        if _INT64[0] <= value <= _INT64[1]:
            return value
    if text in _YAML_INF_NAN:
        return _YAML_INF_NAN[text]
    if _C_FLOAT.fullmatch(text):
        number = text.strip()
        hexadecimal = re.match(r"[-+]?0[xX]", number) is not None
        value = float.fromhex(number) if hexadecimal else float(number.split("(")[0])
        if not math.isinf(value) or re.search(r"[iI][nN][fF]", number):
            if not _underflows(number, value, hexadecimal):   # strtod's ERANGE: rcl takes the text instead
                return value
    return text


def _underflows(number: str, value: float, hexadecimal: bool) -> bool:
    """Whether glibc's strtod says ERANGE for an underflow: a result below the smallest normal double that is
    not exact (``1e-400`` as 0, ``4.9e-324``, ``2.2250738585072011e-308``; ``0x1p-1074`` is exact)."""
    if math.isnan(value) or math.isinf(value) or abs(value) >= sys.float_info.min:
        return False
    match = re.fullmatch(r"[-+]?0[xX]([0-9a-fA-F]*)\.?([0-9a-fA-F]*)(?:[pP]([-+]?[0-9]+))?", number)
    if value == 0.0:      # a zero written as one, or a number too small for a double
        mantissa = match.group(1) + match.group(2) if hexadecimal else re.split(r"[eE]", number)[0]
        return re.search(r"[1-9a-fA-F]", mantissa) is not None
    if not hexadecimal:
        return True
    whole, fraction, exponent = match.groups()
    exact = Fraction(int(whole + fraction or "0", 16)) * Fraction(2) ** (int(exponent or 0) - 4 * len(fraction))
    return Fraction(abs(value)) != abs(exact)


def parse_params(text: str, name: str = "parameters file") -> dict:
    """``{node name: {ros__parameters: {...}}, ...}`` from the text of a parameter file, as rcl reads it:
    every document merged, nested node names and parameter names kept nested. A file that is a bare value
    (or empty) gives ``{}``, as rcl takes it. :class:`ParamsFileError` for what rcl refuses."""
    import yaml

    try:
        check_yaml_depth(text)
        documents = list(yaml.compose_all(text, Loader=_event_tags_loader()))
    except yaml.YAMLError as exc:
        raise ParamsFileError(f"{name}: not valid YAML ({str(exc).splitlines()[0]})") from None
    out: dict = {}
    key_next = True     # rcl reads the documents as one stream of keys and values: a scalar document is a key
    for document in documents:
        if isinstance(document, yaml.SequenceNode):
            raise ParamsFileError(f"{name}: a list where node names belong (line {_line(document)})")
        if isinstance(document, yaml.ScalarNode) and document.value == "":
            raise ParamsFileError(f"{name}: an empty document (line {_line(document)})")
        if not key_next:
            raise ParamsFileError(f"{name}: a document after a document that is a single value"
                                  f" (line {_line(document)})")
        if isinstance(document, yaml.ScalarNode):
            key_next = False
            continue
        _merge(out, _node_names(document, (), name))
    return out


def read_params_file(path: str | Path) -> dict:
    """:func:`parse_params` of a file; one line naming it when it cannot be read or rcl would refuse it."""
    text = read_text(path, "ROS parameters file", ParamsFileError)
    try:
        return parse_params(text, str(path))
    except ParamsFileError as exc:
        raise ParamsFileError(f"{exc} (ROS refuses the whole file)") from None


def parameters_for(doc: dict, node: str, namespace: str = "/") -> dict:
    """The parameters ``doc`` (from :func:`parse_params`) gives the node ``namespace/node``, their nested
    names dotted (``part_ids: {torso: 7}`` is ``part_ids.torso``), later sections winning, as rcl applies
    them: a section's name may be the node's name, its full name, or a pattern (``/**``, ``/*/node``)."""
    out: dict = {}
    for _, params in sections_for(doc, node, namespace):
        out.update(params)
    return out


def sections_for(doc: dict, node: str, namespace: str = "/") -> list:
    """``[(section name, {dotted name: value})]``: each section of ``doc`` that rcl applies to the node
    ``namespace/node``, in the order it applies them."""
    full = "/".join(filter(None, namespace.strip("/").split("/") + [node]))
    return [(section, _dotted(params)) for section, params in _sections(doc, ()) if _matches(section, full)]


def names_the_node(section: str) -> bool:
    """A section that names its node (``calibrate``, ``/**/calibrate``), not one for any node (``/**``,
    ``/nao2/*``): a parameter there the node does not have is a mistake, not one meant for another node."""
    tokens = [t for t in section.strip("/").split("/") if t]
    return bool(tokens) and tokens[-1] not in ("*", "**")


def _sections(doc: dict, trail: tuple):
    for key, value in doc.items():
        if key == PARAMETERS_KEY:
            yield "/".join(trail), value
        else:
            yield from _sections(value, trail + (key,))


def _matches(pattern: str, full: str) -> bool:
    """rcl's node name match: ``**`` any number of name parts, ``*`` one."""
    tokens = [t for t in pattern.strip("/").split("/") if t]
    if not tokens or tokens == ["**"]:
        return tokens == ["**"]
    regex = "/".join("(.+)" if t == "**" else "[^/]+" if t == "*" else re.escape(t) for t in tokens)
    regex = regex.replace("(.+)/", "(?:.+/)?")
    return re.fullmatch(regex, full) is not None


def _dotted(params: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in params.items():
        if isinstance(value, dict):
            out.update(_dotted(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _merge(into: dict, more: dict) -> None:
    """A node or namespace given twice gathers both sections; a parameter given twice keeps the later value."""
    for key, value in more.items():
        if isinstance(value, dict) and isinstance(into.get(key), dict):
            _merge(into[key], value)
        else:
            into[key] = value


def _line(node) -> int:
    return node.start_mark.line + 1


def _key(node, name: str) -> str:
    import yaml

    if not isinstance(node, yaml.ScalarNode):
        raise ParamsFileError(f"{name}: a {'list' if isinstance(node, yaml.SequenceNode) else 'mapping'} as a key"
                              f" (line {_line(node)})")
    if node.value == "":
        raise ParamsFileError(f"{name}: an empty name (line {_line(node)})")
    return node.value


_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NODE_NAME_MAX, _NAMESPACE_MAX = 255, 245      # rmw's limits


def _check_node_name(trail: tuple, line: int, name: str) -> None:
    """rcl's check of the name whose ``ros__parameters`` follow: the keys ``trail`` joined by ``/`` (no second
    one after a key ending in ``/``), a namespace, each part a ROS name (a letter or ``_``, then letters, digits
    or ``_``) or ``*`` or ``**``, then the node's name or ``*`` or ``**``: no empty part (``//``, a name ending in
    ``/``, a nested key starting with ``/``)."""
    full = ""
    for key in trail:
        full += key if not full or full.endswith("/") else "/" + key
    if full in ("/**", "/*"):
        return
    namespace, _, node = full.rpartition("/")
    parts = namespace.removeprefix("/").split("/") if namespace else []
    bad = [p for p in parts if p not in ("*", "**") and not (_NAME_TOKEN.fullmatch(p) and len(p) < _NAMESPACE_MAX)]
    if bad or (node not in ("*", "**") and not (_NAME_TOKEN.fullmatch(node) and len(node) <= _NODE_NAME_MAX)):
        raise ParamsFileError(f"{name}: '{full}' is not a ROS node name (a namespace and a name, each part a letter"
                              f" or '_', then letters, digits or '_'; or * or **) (line {line})")


def _pairs(node, name: str):
    import yaml

    if node.tag == "tag:yaml.org,2002:merge" or any(k.tag == "tag:yaml.org,2002:merge" for k, _ in node.value):
        raise ParamsFileError(f"{name}: '<<' merges are not read by ROS (line {_line(node)})")
    for key_node, value_node in node.value:
        if _is_alias(key_node):
            raise ParamsFileError(f"{name}: an alias (*name), which ROS does not read (line {_line(key_node)})")
        _seen(key_node)
        if _is_alias(value_node):
            raise ParamsFileError(f"{name}: an alias (*name), which ROS does not read (line {_line(key_node)})")
        yield _key(key_node, name), value_node


def _is_alias(node) -> bool:
    # the composer hands an alias back as the very node its anchor named, already seen: rcl refuses aliases
    return getattr(node, "_nao_skin_seen", False)


def _seen(node) -> None:
    if getattr(node, "_nao_skin_seen", False):
        return
    node._nao_skin_seen = True


def _node_names(node, trail: tuple, name: str) -> dict:
    """A mapping of node names (or namespaces) down to ``ros__parameters``."""
    import yaml

    _seen(node)
    out: dict = {}
    for key, value in _pairs(node, name):
        where = "/".join(trail + (key,))
        if key.startswith(PARAMETERS_KEY):      # rcl compares the key's start only
            key = PARAMETERS_KEY
            _check_node_name(trail, _line(value), name)
            if not isinstance(value, yaml.MappingNode):
                raise ParamsFileError(f"{name}: '{where}' must map parameter names to values (line {_line(value)})")
            _merge(out, {key: _parameters(value, trail, "", name)})
        elif isinstance(value, yaml.MappingNode):
            _merge(out, {key: _node_names(value, trail + (key,), name)})
        else:
            raise ParamsFileError(f"{name}: '{where}' is a value where a node name maps to its ros__parameters"
                                  f" (line {_line(value)})")
    return out


def _parameters(node, trail: tuple, prefix: str, name: str) -> dict:
    import yaml

    _seen(node)
    out: dict = {}
    for key, value in _pairs(node, name):
        where = f"{'/'.join(trail)}.{prefix}{key}"
        if isinstance(value, yaml.MappingNode):
            _merge(out, {key: _parameters(value, trail, f"{prefix}{key}.", name)})
        elif isinstance(value, yaml.SequenceNode):
            out[key] = _array(value, where, name)
        else:
            _seen(value)
            out[key] = _scalar(value, where, name)
    return out


def _scalar(node, where: str, name: str):
    quoted = node.style in ("'", '"') or node.tag == _STR_TAG
    if not quoted and node.value == "":
        raise ParamsFileError(f"{name}: {where} has no value (line {_line(node)})")
    return scalar_value(node.value, quoted)


def _array(node, where: str, name: str) -> list | None:
    """A list of one type; no item is no value at all (the parameter is not set). rcl takes lists and
    mappings inside a list too, but what it makes of them is an accident of its event loop (``[[1], 2]`` is
    ``[1]`` and a parameter named ``2``): a nested list's items are read as if they stood in the list, a
    nested mapping is passed over."""
    import yaml

    _seen(node)
    values = []
    for item in node.value:
        if _is_alias(item):
            raise ParamsFileError(f"{name}: an alias (*name), which ROS does not read (line {_line(item)})")
        if isinstance(item, yaml.SequenceNode):
            values += _array(item, where, name) or []
        elif isinstance(item, yaml.MappingNode):
            continue
        else:
            _seen(item)
            values.append(_scalar(item, where, name))
    kinds = {float if isinstance(v, float) else type(v) for v in values}
    if len(kinds) > 1:
        words = {bool: "booleans", int: "integers", float: "numbers", str: "strings"}
        raise ParamsFileError(f"{name}: {where} mixes {' and '.join(sorted(words[k] for k in kinds))} in one list"
                              f" (line {_line(node)})")
    return values or None
