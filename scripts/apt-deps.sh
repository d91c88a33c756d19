#!/usr/bin/env bash
# Installs the Debian packages headless rendering needs, only those missing.
set -euo pipefail
pkgs="libegl1 libegl-mesa0 libgl1-mesa-dri libgbm1 libosmesa6"
missing=""
for p in $pkgs; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "apt-get install:$missing"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
fi
