#!/usr/bin/env bash
# Installs the Debian packages the tests and the corpus builder need, when any is missing.
# Speech synthesizers and soundfonts build the sound corpora; PostgreSQL backs the compose-profile tests;
# Chromium drives the browser tests. `make run` needs none of them.
set -euo pipefail

packages=(espeak-ng flite festival festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts
          fluidsynth timgm6mb-soundfont fluid-soundfont-gm timidity freepats
          postgresql chromium)

missing=()
for pkg in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
[ ${#missing[@]} -eq 0 ] && exit 0

if [ "$(id -u)" -ne 0 ]; then
    echo "Missing Debian packages: ${missing[*]}" >&2
    echo "Install them with: sudo apt-get install -y ${missing[*]}" >&2
    echo "(tests that need them are skipped with this reason)" >&2
    exit 0
fi
echo "Installing Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null
apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null
