#!/usr/bin/env bash
# Refresh requirements.lock, the exact version of every package the project installs.
#
#   bash scripts/lock.sh
#
# Resolves pyproject.toml's dependencies and every extra afresh, in a scratch venv, and pins
# what pip chose. README's commands and .ci/run install with `-c requirements.lock`, so a
# fresh machine gets these versions whatever the package index serves on the day. Review
# the diff, run the tests, and commit the lock with the reason for the change.
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
python3 -m venv "$tmp/venv"
"$tmp/venv/bin/pip" install -q -e ".[dev,mcap,cluster,physics,mutation,live]"
{
  echo "# Every package version formation-ilc installs, for Python $(python3 -c 'import sys; print("%d.%d" % sys.version_info[:2])') on Linux."
  echo "# Made by scripts/lock.sh (run it to refresh); used as pip constraints:"
  echo "#   pip install -c requirements.lock -e \".[dev,mcap,cluster,physics,live]\""
  "$tmp/venv/bin/pip" freeze --exclude-editable --all | grep -v -i -E '^(pip|setuptools|wheel)=='
} > requirements.lock.new
mv requirements.lock.new requirements.lock
echo "requirements.lock: $(grep -c '==' requirements.lock) packages pinned"
