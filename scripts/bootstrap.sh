# Sourced by scripts/run and scripts/test: a virtual environment in .venv with fleethealth
# installed (editable, with test and benchmark extras), re-installed only when pyproject.toml changes.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
python=${PYTHON:-python3}
if ! "$python" -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null; then
  echo "fleethealth needs Python 3.11 or newer (set PYTHON=/path/to/python3.11)" >&2
  exit 1
fi
if [ ! -x .venv/bin/python ]; then
  echo "creating the virtual environment in .venv" >&2
  "$python" -m venv .venv
fi
stamp=.venv/.fleethealth-installed
want=$(cat pyproject.toml | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "installing fleethealth and its dependencies into .venv" >&2
  log=.venv/install.log
  if ! { .venv/bin/python -m pip install --upgrade pip && .venv/bin/python -m pip install -e ".[test,bench]"; } >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "installation failed; the whole log is in $log" >&2
    exit 1
  fi
  echo "$want" > "$stamp"
fi
export PATH="$root/.venv/bin:$PATH"
