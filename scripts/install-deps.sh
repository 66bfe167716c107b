#!/usr/bin/env bash
# Installs terralign's build and test dependencies from Debian 12's packages, when missing.
# Runs as root or through sudo. Extra package names may be given as arguments.
set -euo pipefail
pkgs=(cmake g++ make pkg-config libeigen3-dev libstb-dev libgeographiclib-dev doctest-dev
      libtiff-dev nlohmann-json3-dev locales "$@")
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "installing: ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
# A locale with a decimal comma, which a test sets as a caller might
# (tests/test_caller_environment.cpp): terralign's numbers must not depend on it.
if ! locale -a 2>/dev/null | grep -qiE '^de_DE\.utf-?8$'; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO localedef -i de_DE -f UTF-8 de_DE.UTF-8
fi
