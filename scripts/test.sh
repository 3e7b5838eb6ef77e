#!/usr/bin/env bash
# Install everything the test suite needs on a fresh machine (system packages, handeye with its
# test extras), run the gates (ruff, ruff format, mypy) and the whole suite on all cores. CI (.ci/run)
# calls exactly this; a gate that fails stops it before the tests.
set -euo pipefail
cd "$(dirname "$0")/.."
if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
  need=""
  ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || need="$need libusb-1.0-0"   # pyrealsense2 imports it
  command -v chromium >/dev/null 2>&1 || need="$need chromium"                    # report rendering tests
  if [ -n "$need" ]; then
    # the tests that need these skip with a reason when they are missing, so a failed apt is a warning
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $need >/dev/null; } \
      || echo "scripts/test.sh: warning: could not install$need; the tests that need them will skip" >&2
  fi
fi
python3 -m pip install -q --disable-pip-version-check -e '.[test]'
# the gates: lint, formatting and types (configured in pyproject.toml; the same as .pre-commit-config.yaml)
python3 -m ruff check -q .
python3 -m ruff format --check -q .
python3 -m mypy --no-error-summary
exec python3 -m pytest -p no:benchmark -n "${HANDEYE_TEST_WORKERS:-2}" "$@"
