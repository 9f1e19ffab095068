#!/usr/bin/env bash
# A headless Chromium for the viewer's browser tests and benchmark (tests/test_viewer_browser.py,
# bench/viewer.py; the DevTools protocol is spoken directly, no chromedriver needed).
# Idempotent: does nothing when a Chromium-family browser is already on the PATH or
# CLRASTER_CHROMIUM names one; otherwise installs Debian/Ubuntu's chromium with apt-get.
set -euo pipefail
if [ -n "${CLRASTER_CHROMIUM:-}" ] || command -v chromium >/dev/null 2>&1 \
        || command -v chromium-browser >/dev/null 2>&1 || command -v google-chrome >/dev/null 2>&1; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "install_browser: no apt-get here: install Chromium or Chrome, or set CLRASTER_CHROMIUM" >&2
    exit 0   # the browser tests then skip, saying why
fi
sudo_cmd=""
[ "$(id -u)" = 0 ] || sudo_cmd="sudo"
echo "install_browser: installing chromium (apt-get)" >&2
$sudo_cmd apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq chromium >/dev/null
