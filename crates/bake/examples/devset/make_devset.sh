#!/usr/bin/env bash
# Renders the development set (see README.md next to this script) into OUT_DIR.
#
#   crates/bake/examples/devset/make_devset.sh OUT_DIR [--quick] [--only NAME ...]
#
# Makes a Python 3.11 virtual environment with the pinned Blender `bpy` wheel under the
# repository's .tools/devset-venv (once; PyPI through pip), then runs make_devset.py.
# Other arguments pass through to make_devset.py (see its --help). Rerunning resumes:
# finished captures are skipped and rendered frames are kept.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../../../.." && pwd)"
venv="$root/.tools/devset-venv"
req="$here/requirements.txt"

if [[ $# -lt 1 || "$1" == -h || "$1" == --help ]]; then
    sed -n '2,9p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
    exit $([[ $# -lt 1 ]] && echo 2 || echo 0)
fi

find_python() {
    for py in "${PYTHON:-}" python3.11 python3; do
        [[ -n "$py" ]] || continue
        command -v "$py" >/dev/null 2>&1 || continue
        if [[ "$("$py" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" == 3.11 ]]; then
            echo "$py"
            return 0
        fi
    done
    return 1
}

if ! cmp -s "$req" "$venv/requirements.installed" 2>/dev/null; then
    py="$(find_python)" || {
        echo "make_devset.sh: needs Python 3.11 (the bpy 5.0.1 wheel is built for it); set PYTHON=/path/to/python3.11" >&2
        exit 1
    }
    echo "make_devset.sh: installing the pinned environment into $venv" >&2
    rm -rf "$venv"
    "$py" -m venv "$venv"
    "$venv/bin/pip" install --quiet --disable-pip-version-check -r "$req"
    cp "$req" "$venv/requirements.installed"
fi

exec "$venv/bin/python" "$here/make_devset.py" "$@"
