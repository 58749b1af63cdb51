#!/usr/bin/env bash
# The whole test suite: lint, format check, types, then every test (slow ones included).
set -euo pipefail
cd "$(dirname "$0")/.."
. .venv/bin/activate
echo "== ruff"; ruff check . && ruff format --check .
echo "== mypy"; mypy api_schemas workers service eigenscope client/src/eigenscope_client
echo "== pytest"; pytest "$@"
