#!/usr/bin/env bash
# Set up (or confirm) the repository's Python environment in .venv: the pinned requirements,
# softseq_ros itself in editable mode, and the ament index entries that an editable install
# does not create. Safe to run any number of times; does no pip work when nothing changed.
#
# Environment: PYTHON picks the interpreter used to create .venv (default: python3.11, then
# python3). It must be Python 3.11 because the ROS 2 Jazzy wheels are built for it.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/.venv"
package=softseq_ros
log="$venv/bootstrap.log"
stamp="$venv/.softseq_bootstrap_stamp"

fail() {
    echo "bootstrap: error: $*" >&2
    exit 1
}

# The hash covers everything that decides what pip installs, and this script itself.
inputs_hash() {
    cat "$repo/requirements.txt" "$repo/setup.py" "$repo/setup.cfg" "$repo/tools/bootstrap.sh" \
        | sha256sum | cut -d' ' -f1
}

pick_python() {
    if [[ -n "${PYTHON:-}" ]]; then
        command -v "$PYTHON" || fail "PYTHON=$PYTHON is not an executable on PATH"
    elif command -v python3.11 >/dev/null 2>&1; then
        command -v python3.11
    elif command -v python3 >/dev/null 2>&1; then
        command -v python3
    else
        fail 'no python3 found; install Python 3.11 (Debian 12: apt-get install python3 python3-venv)'
    fi
}

create_venv() {
    local python version
    python="$(pick_python)"
    version="$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
    [[ "$version" == 3.11 ]] \
        || fail "$python is Python $version; the pinned ROS 2 Jazzy wheels need Python 3.11"
    "$python" -m venv "$venv" >/dev/null 2>&1 || {
        rm -rf "$venv"
        fail "'$python -m venv' failed (Debian: apt-get install python3-venv)"
    }
}

run_pip() {
    # No prompts: this runs in CI and without a terminal. Details go to the log, not the screen.
    PIP_NO_INPUT=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
        "$venv/bin/python" -m pip install --quiet "$@" </dev/null >>"$log" 2>&1 || {
        echo "bootstrap: error: 'pip install $*' failed; last lines of $log:" >&2
        tail -n 15 "$log" >&2
        exit 1
    }
}

# pip install -e installs no data_files, so write the ament index entries that ros2 run and
# ament_index_python look for under the venv prefix (AMENT_PREFIX_PATH=.venv). Links keep the
# share folder in step with the working tree, as the editable install does for the code.
link_ament_share() {
    local share="$venv/share"
    mkdir -p "$share/ament_index/resource_index/packages" "$share/$package"
    cp "$repo/resource/$package" "$share/ament_index/resource_index/packages/$package"
    local item
    for item in package.xml config; do
        if [[ -e "$share/$package/$item" && ! -L "$share/$package/$item" ]]; then
            rm -rf "${share:?}/$package/$item"  # a copy left by a non-editable install
        fi
        ln -sfn "$repo/$item" "$share/$package/$item"
    done
}

[[ -f "$repo/requirements.txt" ]] || fail "$repo/requirements.txt is missing"

if [[ ! -x "$venv/bin/python" ]]; then
    [[ -e "$venv" ]] && fail "$venv exists but has no bin/python; delete it and run again"
    create_venv
fi
# A venv holds absolute paths in its scripts' first lines; after the repository moved, every
# console script (pytest, ruff, colcon) would fail with a puzzling "No such file".
if [[ -f "$venv/bin/pip" && "$(head -n 1 "$venv/bin/pip")" != "#!$venv/bin/python"* ]]; then
    fail "$venv was created at another path (the repository moved); delete it and run again"
fi

# Two scripts bootstrapping at once (test and demo) must not run pip side by side.
exec 9>"$venv/.bootstrap.lock"
if command -v flock >/dev/null 2>&1; then
    flock 9
fi

wanted="$(inputs_hash)"
if [[ ! -f "$stamp" || "$(cat "$stamp")" != "$wanted" ]]; then
    echo 'bootstrap: installing Python dependencies into .venv (the first run takes a few minutes)'
    : >"$log"
    run_pip -r "$repo/requirements.txt"
    run_pip --no-deps -e "$repo"
    echo "$wanted" >"$stamp"
    echo 'bootstrap: .venv is ready'
fi

link_ament_share

# An editable install compiles nothing, and where PYTHONDONTWRITEBYTECODE is set Python keeps
# nothing it compiles: every command would compile the package anew (a tenth of a second of
# each `softseq report`). Files already compiled and unchanged are skipped.
"$venv/bin/python" -m compileall -q "$repo/$package"
