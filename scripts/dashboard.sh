#!/usr/bin/env bash
# Set up the environment and open the dashboard on the bundled sample logs.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/bootstrap.sh
exec .venv/bin/solarnav dashboard "$@"
