#!/usr/bin/env bash
# Installs the Debian packages the tests and the corpus builder need, when any is missing; fails (exit 1, with
# what to do) when one is missing and cannot be installed, so a CI that lost one goes red instead of skipping.
# Speech synthesizers and soundfonts build the sound corpora; PostgreSQL backs the compose-profile tests;
# Chromium drives the browser tests. `make run` needs none of them.
set -euo pipefail

packages=(espeak-ng flite festival festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts
          fluidsynth timgm6mb-soundfont fluid-soundfont-gm timidity freepats
          postgresql chromium)

missing_packages() {
    for pkg in "${packages[@]}"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || echo "$pkg"
    done
}

fail() {
    echo "install-system-packages: $1" >&2
    echo "The tests need them; install them with: sudo apt-get install -y ${missing[*]}" >&2
    exit 1
}

mapfile -t missing < <(missing_packages)
[ ${#missing[@]} -eq 0 ] && exit 0

[ "$(id -u)" -eq 0 ] || fail "missing Debian packages: ${missing[*]} (not root, so not installing them)"
echo "Installing Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
apt-get update -q >/dev/null || fail "apt-get update failed; missing Debian packages: ${missing[*]}"
apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null \
    || fail "apt-get install failed; missing Debian packages: ${missing[*]}"
mapfile -t missing < <(missing_packages)
[ ${#missing[@]} -eq 0 ] || fail "still missing after apt-get install: ${missing[*]}"
