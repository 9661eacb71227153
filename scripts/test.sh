#!/usr/bin/env bash
# Install the test dependencies and run the whole suite (unit tests, real-data tests
# that skip when ../shared/data is absent, headless-browser report tests, ruff and mypy).
# This is the README's test command.
set -euo pipefail
cd "$(dirname "$0")/.."
# Headless Chromium for the report tests (Debian package; needs root, as on CI).
if ! command -v chromium >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
        || echo "warning: could not install chromium; browser tests will skip" >&2
fi
python3 -m pip install --quiet --disable-pip-version-check -e ".[test]"
# One pytest worker per core (pytest-xdist): on a fresh clone most of the time is numba
# compiling the filters into its cache, and the workers compile different ones side by side
# (on 2 cores, a fresh clone's .ci/run: 8 min 25 s -> 3 min 59 s, docs/RESULTS.md 24).
# Arguments come after, so "-n 0" runs in one process.
python3 -m pytest -n auto "$@"
