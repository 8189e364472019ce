#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment in .venv, install solarnav into it and compile the
# estimators once (warm numba's cache; skipped in a few seconds when it is warm).
# Usage: scripts/bootstrap.sh [dev]   ("dev" adds the test tools)
# Environment: PYTHON (interpreter that creates the venv, default python3), SOLARNAV_VENV (default .venv),
#              SOLARNAV_SKIP_WARMUP=1 (do not compile now; the first replay then compiles and says so).
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-python3}"
VENV="${SOLARNAV_VENV:-.venv}"
if [ ! -x "$VENV/bin/python" ]; then
    "$PYTHON" -m venv "$VENV"
fi
want=""
[ "${1:-}" = "dev" ] && want="dev"
# One stamp: its content is the extras installed ("" or "dev"); dev is a superset of the plain install.
stamp="$VENV/.solarnav-installed"
legacy="$VENV/.solarnav-installed[dev]"  # stamp of the dev install before the two were merged
have=""
installed=0
if [ -f "$stamp" ]; then
    installed=1
    have="$(cat "$stamp")"
fi
if [ -f "$legacy" ]; then
    if [ "$installed" = 0 ] || [ "$legacy" -nt "$stamp" ]; then
        echo dev > "$stamp"
        touch -r "$legacy" "$stamp"  # its time, so a newer pyproject.toml still triggers a reinstall
        installed=1
        have="dev"
    fi
    rm -f "$legacy"
fi
extras="$want"
[ "$have" = "dev" ] && extras="dev"  # never downgrade: a dev install stays one
# Reinstall when nothing is installed, pyproject.toml changed since the install, or dev is needed but missing.
needs_install() {
    [ "$installed" = 0 ] && return 0
    [ pyproject.toml -nt "$stamp" ] && return 0
    [ "$want" = "dev" ] && [ "$have" != "dev" ] && return 0
    return 1
}
if needs_install; then
    spec="."
    [ -n "$extras" ] && spec=".[$extras]"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip
    "$VENV/bin/python" -m pip install --quiet -e "$spec"
    printf '%s\n' "$extras" > "$stamp"
fi
if [ "${SOLARNAV_SKIP_WARMUP:-0}" != "1" ]; then
    "$VENV/bin/python" -m estimators.warmup
fi
