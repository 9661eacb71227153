#!/usr/bin/env bash
# Install the test dependencies and run the whole suite (unit tests, real-data tests
# that skip when ../shared/data is absent, ruff and mypy). This is the README's test command.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --disable-pip-version-check -e ".[test]"
python3 -m pytest "$@"
