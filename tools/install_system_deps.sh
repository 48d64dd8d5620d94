#!/usr/bin/env bash
# Installs the Debian packages MuJoCo's offscreen rendering needs (EGL through Mesa's
# llvmpipe on CPU-only machines, OSMesa as the fallback). Does nothing when they are
# present; warns, without failing, where it cannot install (no root, no apt).
set -u
packages=(libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
if ! command -v apt-get >/dev/null 2>&1; then
  echo "warning: cannot install ${missing[*]} (no apt-get); offscreen rendering needs them." >&2
  exit 0
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then sudo="sudo -n"; else
    echo "warning: run 'sudo apt-get install ${missing[*]}' for offscreen rendering." >&2
    exit 0
  fi
fi
echo "installing ${missing[*]} (offscreen rendering)"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq >/dev/null && \
  $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null || \
  echo "warning: apt-get could not install ${missing[*]}; offscreen rendering needs them." >&2
exit 0
