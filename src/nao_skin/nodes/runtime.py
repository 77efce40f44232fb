"""Starting and stopping nao_skin nodes: one place for rclpy set-up, parameters and clean shutdown.

Every node module has ``main(args=None)`` calling :func:`run_node`: it
initialises rclpy (``--ros-args`` from the command line, so ``ros2 run``,
``ros2 launch`` and ``nao-skin record`` pass parameters the same way), spins
until SIGINT, SIGTERM or SIGHUP (terminal closed), then calls the node's
``close()`` so that buffered data is written before the process ends. A node
started by ``nao-skin record`` or by our launch files (:data:`~nao_skin.session.record.PARENT_ENV`
set) stops the same way when that process is gone, however it ended.
"""
from __future__ import annotations

import array
import functools
import os
import re
import signal
import sys
import threading
from collections import Counter

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import InvalidParameterTypeException, ParameterUninitializedException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter

from nao_skin.errors import STOP_SIGNALS, ConfigError, DataError, NaoSkinError, ignore_stop_signals
from nao_skin.rules import did_you_mean
from nao_skin.session.params import at_start_said, rule_range
from nao_skin.session.record import PARENT_ENV

MAX_LOGGED_FAILURES = 5   # callback errors of one kind logged one by one (then every 100th)

def declare(node, params: dict, changeable=(), on_change=None) -> dict:
    """Declare ``{name: (default, description[, rule])}`` and return ``{name: value}``.

    A float parameter (or list of floats) also takes integers, as people
    write them (``-p gate_mm:=20``, ``gate_mm: 20`` in a params file): it is
    stored as a float, so it keeps its type for introspection and the node.
    Any other type mismatch, or a value its :class:`~nao_skin.rules.Rule`
    refuses (``rate:=0``), is a one-line ConfigError naming the parameter;
    later changes (``ros2 param set``) are held to the same.

    Each parameter's descriptor (``ros2 param describe``) carries its help, its rule (``additional_constraints``,
    and a range where the rule is one) and ``read_only`` unless it is in ``changeable`` (a set of names, or a
    function of the values read returning one): those the node applies when they are set, in
    ``on_change({name: value})``, called after the change was accepted; the others are refused, saying that
    the node reads them when it starts.
    """
    out, numeric, rules = {}, {}, {}
    for name, (default, text, *rule) in params.items():
        if _is_float(default):
            # declared with dynamic typing only to let an integer in; set back to float right away
            node.declare_parameter(name, default, ParameterDescriptor(description=text, dynamic_typing=True))
            value = node.get_parameter(name).value
            number = _as_float(value, default)
            if number is None:
                raise ConfigError(f"node '{node.get_name()}': parameter '{name}' must be"
                                  f" {'a list of numbers' if isinstance(default, list) else 'a number'}"
                                  f" like {default!r}, not {'an empty list' if value is None else repr(value)}")
            kind = Parameter.Type.from_parameter_value(default)
            if node.get_parameter(name).type_ != kind:
                result = node.set_parameters([Parameter(name, kind, number)])[0]
                if not result.successful:
                    raise ConfigError(f"node '{node.get_name()}': parameter '{name}': {result.reason}")
            numeric[name] = default
        else:
            try:
                node.declare_parameter(name, default, ParameterDescriptor(description=text))
            except InvalidParameterTypeException as exc:
                given = str(exc).rsplit(f": {name}", 1)[0]        # rclpy appends ": <name>"
                raise ConfigError(f"node '{node.get_name()}': parameter '{name}' takes a value like {default!r}"
                                  f" ({given})") from None
        try:
            out[name] = node.get_parameter(name).value
        except ParameterUninitializedException:   # '-p name:=[]': an empty list has no type for rcl
            if not isinstance(default, list):
                raise ConfigError(f"node '{node.get_name()}': parameter '{name}' takes a value like {default!r},"
                                  f" not an empty list") from None
            out[name] = []
        if rule:
            rules[name] = rule[0]
            try:
                rule[0].check(f"node '{node.get_name()}': parameter {name}:={out[name]!r}", out[name])
            except DataError as exc:
                raise ConfigError(str(exc)) from None
    changeable = set(changeable(out) if callable(changeable) else changeable) & set(params)
    for name, (default, text, *rule) in params.items():
        _describe(node, name, default, text, rule[0] if rule else None, name not in changeable)
    check = functools.partial(_checked, numeric=numeric, rules=rules, declared=set(params), changeable=changeable,
                              node_name=node.get_name())
    node.add_pre_set_parameters_callback(functools.partial(_as_declared, numeric=numeric))
    _checks_first(node, check)
    node.add_on_set_parameters_callback(check)
    if on_change is not None and changeable:
        def applied(changed):
            values = {p.name: _plain(p.value) for p in changed if p.name in changeable}
            if values:
                on_change(values)
        node.add_post_set_parameters_callback(applied)
    return out


def _describe(node, name: str, default, text: str, rule, read_only: bool) -> None:
    """The parameter's full descriptor: help, rule, range, read-only (declared first without them: an integer
    for a float parameter is set back to float, and a value out of range is our one line, not rclpy's)."""
    descriptor = ParameterDescriptor(description=text, read_only=read_only,
                                     type=Parameter.Type.from_parameter_value(default).value)
    said = [rule.describe()] if rule is not None else []
    if read_only:
        said.append(f"read when the node starts ({at_start_said(node.get_name(), name)})")
    descriptor.additional_constraints = "; ".join(said)
    bounds = rule_range(default, rule)
    if bounds is not None and isinstance(default, int):
        descriptor.integer_range = [IntegerRange(from_value=bounds[0], to_value=bounds[1], step=1)]
    elif bounds is not None:
        descriptor.floating_point_range = [FloatingPointRange(from_value=bounds[0], to_value=bounds[1], step=0.0)]
    try:
        node.set_descriptor(name, descriptor)
    except ParameterUninitializedException:    # '-p name:=[]' (no type for rcl): its first descriptor stays
        pass


def _plain(value):
    """A parameter's value as the node reads it at start (a double array arrives as array.array)."""
    return list(value) if isinstance(value, array.array) else value


def _as_declared(changed, numeric: dict) -> list:
    """An integer given for a float parameter (``ros2 param set /calibrate live_period 20``) set as the float it
    is declared as, as at start."""
    out = []
    for p in changed:
        number = _as_float(p.value, numeric[p.name]) if p.name in numeric else None
        if number is not None and p.type_ != Parameter.Type.from_parameter_value(numeric[p.name]):
            p = Parameter(p.name, Parameter.Type.from_parameter_value(numeric[p.name]), number)
        out.append(p)
    return out


def _checks_first(node, check) -> None:
    """``check`` judges a later change before rclpy's own descriptor checks (read-only, range, type), so a
    refusal says the parameter's rule, or how to give it at start, rather than rclpy's bare 'Trying to set a
    read-only parameter'; rclpy's checks and the on-set callbacks run after it as ever. (rclpy has no public
    hook ahead of its descriptors; without this one, its own reasons are said, nothing else changes.)"""
    checks = getattr(node, "_nao_skin_checks", None)
    if checks is None:
        common = getattr(node, "_set_parameters_atomically_common", None)
        if common is None:
            return
        checks = node._nao_skin_checks = []

        def ours_first(parameter_list, descriptors=None, allow_not_set_type=False):
            if descriptors is None:        # a change, not a declaration nor a new descriptor
                for c in checks:
                    result = c(parameter_list)
                    if not result.successful:
                        return result
            return common(parameter_list, descriptors, allow_not_set_type)

        node._set_parameters_atomically_common = ours_first
    checks.append(check)


def _is_float(default) -> bool:
    return isinstance(default, float) or (isinstance(default, (list, tuple)) and len(default) > 0
                                          and all(isinstance(v, float) for v in default))


def _as_float(value, default):
    """``value`` as the float (or list of floats) ``default`` is; None when it is not numbers."""
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    if isinstance(default, float):
        return float(value) if number(value) else None
    if isinstance(value, (list, tuple, array.array)) and all(number(v) for v in value):
        return [float(v) for v in value]
    return None


def _checked(changed, numeric: dict, rules: dict, declared: set, changeable: set = frozenset(),
             node_name: str = "NODE") -> SetParametersResult:
    """Later changes (``ros2 param set``): numbers only for a float parameter, and within its rule, as at
    declaration; a valid value of a parameter the node reads only when it starts is refused too, saying so:
    taking the value without using it would tell the user it did."""
    for p in changed:
        if p.name not in declared:
            continue
        if p.name in numeric and _as_float(p.value, numeric[p.name]) is None:
            return SetParametersResult(successful=False, reason=f"'{p.name}' takes a number like {numeric[p.name]!r}")
        if p.name in rules:
            value = _plain(p.value)   # a double array's values
            try:
                rules[p.name].check(f"parameter {p.name}:={value!r}", value)
            except DataError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if p.name not in changeable:
            return SetParametersResult(successful=False,
                                       reason=f"'{p.name}' is read when the node starts: restart the node with"
                                              f" it ({at_start_said(node_name, p.name)})")
    return SetParametersResult(successful=True)


def _check_params_files(args) -> None:
    """Each ``--params-file`` of the ROS arguments one that rcl reads (where it refuses one, it says so in two
    lines, one a log line): the same rules as rcl's, so a file rcl takes is never refused here."""
    from nao_skin.formats.ros_params import read_params_file

    args = list(args)
    for i, arg in enumerate(args[:-1]):
        if arg == "--params-file" and not read_params_file(args[i + 1]):
            # rcl takes a file that is a single value (or empty) without a word: the node runs on its defaults
            print(f"warning: {args[i + 1]}: gives no node any parameter", file=sys.stderr)


def _warn_undeclared(node) -> None:
    """One warning naming the parameters given to the node that it does not declare (a typo, or a mapping
    where a value belongs: ``rate: {hz: 5}`` arrives as ``rate.hz``), which ROS ignores without a word.
    A warning, not an error: a ``/**`` section of a parameters file rightly gives every node the same set."""
    given = getattr(node, "_parameter_overrides", {})     # rclpy keeps the overrides there, undeclared ones too
    unknown = sorted(name for name in given if not node.has_parameter(name))
    if not unknown:
        return
    declared = list(node.get_parameters_by_prefix(""))
    # 'rate.hz' (a mapping where a value belongs) is closest to 'rate' by its first part
    hints = [name + (did_you_mean(name, declared) or did_you_mean(name.split(".")[0], declared)) for name in unknown]
    node.get_logger().warning(f"ignored parameters this node does not have: {', '.join(hints)}")


def _rcl_reason(exc: Exception) -> str:
    """rcl's message without its source locations (', at /project/src/...')."""
    text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return re.sub(r", at /\S+:\d+", "", text).removeprefix("failed to initialize rcl: ")


def _parent_gone():
    """A check "has the process that started this node gone?" for a node ``nao-skin record`` or a launch file of
    ours started (:data:`~nao_skin.session.record.PARENT_ENV`), else None.

    Reparenting (our parent died) or the named pid vanishing both mean gone:
    the fallback where the kernel's parent-death signal is not available.
    """
    text = os.environ.get(PARENT_ENV, "")
    if not (text.isascii() and text.isdigit()):
        return None
    parent, ppid = int(text), os.getppid()

    def gone() -> bool:
        if os.getppid() != ppid:
            return True
        try:
            os.kill(parent, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            pass
        return False

    return gone


def _spin_once(executor, node, failures: Counter) -> None:
    """One turn of the executor. Any other error of a callback (a request rclpy's own parameter service
    cannot parse, a bug) is said in a line and skipped: a node that ended for it would end the whole
    recording session for one bad message. The first few of each kind are logged, then every 100th."""
    try:
        executor.spin_once(timeout_sec=0.1)
    except (ExternalShutdownException, NaoSkinError):
        raise
    except Exception as exc:     # noqa: BLE001 - whatever a callback raised, the node goes on
        kind = type(exc).__name__
        failures[kind] += 1
        n = failures[kind]
        if n <= MAX_LOGGED_FAILURES or n % 100 == 0:
            node.get_logger().error(f"a callback failed and was skipped ({kind}: {exc}); the node goes on"
                                    + (f" ({n} so far)" if n > 1 else ""))


class _StoppedWhileStarting(Exception):
    """A stop signal arrived while an interruptible node was still being made."""


def run_node(factory, args=None, interruptible_start: bool = False) -> int:
    """Create the node with ``factory()``, spin it, shut it down cleanly on a stop signal or when record is gone.

    ``interruptible_start``: a stop signal aborts ``factory()`` itself (a node that computes for seconds
    before it spins, as sim_robot simulating its touches: else it outlived a killed ``nao-skin record``,
    whose death reaches it as SIGTERM, by that long). Only for a factory that writes nothing.
    """
    args = sys.argv if args is None else args
    try:
        _check_params_files(args)
        rclpy.init(args=args, signal_handler_options=rclpy.SignalHandlerOptions.NO)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RCLError as exc:      # e.g. '-p name:={a: 1}': rcl cannot parse the override
        print(f"error: the ROS arguments: {_rcl_reason(exc)}", file=sys.stderr)
        return 2
    stop = threading.Event()
    starting = [interruptible_start]

    def on_signal(signum, frame):      # noqa: ARG001 - signal handler signature
        stop.set()
        if starting[0]:
            starting[0] = False
            raise _StoppedWhileStarting

    for s in STOP_SIGNALS:
        signal.signal(s, on_signal)
    parent_gone = _parent_gone()
    node = None
    code = 0
    try:
        try:
            node = factory()
            starting[0] = False
        except NaoSkinError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except _StoppedWhileStarting:
            return 0
        _warn_undeclared(node)
        # one thread: a node's callbacks never run concurrently (the recorder's detector is not
        # thread-safe); slow work (polling NAOqi, YARP reads, calibration) has its own threads
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            failures = Counter()
            while not stop.is_set() and rclpy.ok():
                _spin_once(executor, node, failures)
                if parent_gone is not None and parent_gone():
                    node.get_logger().warning(f"the process that started this node (pid {os.environ[PARENT_ENV]}:"
                                              f" nao-skin record or ros2 launch) is gone; stopping")
                    break
        except ExternalShutdownException:
            pass
        except NaoSkinError as exc:      # a callback that cannot go on (e.g. its disk is full) said why
            print(f"error: {exc}", file=sys.stderr)
            code = 2
        finally:
            executor.shutdown(timeout_sec=1.0)
    finally:
        if node is not None:
            close = getattr(node, "close", None)
            if close is not None:
                try:
                    close()
                except NaoSkinError as exc:     # e.g. the last results cannot be written
                    print(f"error: {exc}", file=sys.stderr)
                    code = 2
            node.destroy_node()
        rclpy.try_shutdown()
        # record's SIGTERM arriving during Python's exit (it stops the session just after the recorder
        # said "cannot write the bag") ended the process by the signal, which record counts as a clean
        # stop: exit 0 after a full disk
        ignore_stop_signals()
    return code
