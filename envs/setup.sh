#!/usr/bin/env bash
# Idempotent set-up of a fresh Debian machine (both README commands start with it):
#   1. Debian packages of envs/debian-packages.txt (YADE among them), only those missing;
#   2. .venv made from /usr/bin/python3, the interpreter Debian's YADE is built for;
#   3. YADE's Python modules put on the venv's path with a .pth file (Debian's
#      dist-packages/yade symlink is broken, see docs/environment.md);
#   4. envs/requirements.txt and the project (editable), only when they changed.
# A second run on a set-up machine takes a few seconds.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

YADE_PY=/usr/lib/x86_64-linux-gnu/yade-double/py

missing=()
while read -r pkg; do
  [[ -z "$pkg" || "$pkg" == \#* ]] && continue
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done < envs/debian-packages.txt
if ((${#missing[@]})); then
  echo "setup: installing Debian packages: ${missing[*]}"
  sudo=""; [[ $(id -u) -ne 0 ]] && sudo="sudo"
  $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if [[ ! -d "$YADE_PY/yade" ]]; then
  echo "setup: YADE's Python modules are not at $YADE_PY." >&2
  echo "       Install YADE with: sudo apt-get install -y yade" >&2
  exit 1
fi

[[ -x .venv/bin/python ]] || /usr/bin/python3 -m venv .venv
site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
echo "$YADE_PY" > "$site/yade_debian.pth"

stamp=.venv/.installed.sha256
want=$(cat envs/requirements.txt pyproject.toml | sha256sum | cut -d' ' -f1)
if [[ "$(cat "$stamp" 2>/dev/null)" != "$want" ]]; then
  echo "setup: installing Python requirements into .venv"
  .venv/bin/python -m pip install -q -r envs/requirements.txt
  .venv/bin/python -m pip install -q --no-deps --no-build-isolation -e .
  echo "$want" > "$stamp"
fi

.venv/bin/python -m granular_multiscale.dem.check_yade
