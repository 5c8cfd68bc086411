#!/usr/bin/env bash
# What the tests need besides the Python packages of .venv: chromium (tests/test_view.py opens
# `seeu view` in headless chromium). `make test` runs this first. Installs it with apt-get as root or
# through sudo; otherwise stops with one line saying the command to run.
set -euo pipefail
if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then
  exit 0
fi
install="apt-get install -y chromium"
if ! command -v apt-get >/dev/null 2>&1; then
  echo "make test: chromium is missing (the view tests open it): install it with your package manager, then run make test again" >&2
  exit 1
fi
if [ "$(id -u)" -eq 0 ]; then
  sudo=""
elif command -v sudo >/dev/null 2>&1 && { [ -t 0 ] || sudo -n true 2>/dev/null; }; then
  sudo="sudo"
else
  echo "make test: chromium is missing (the view tests open it): run 'sudo $install' (as root: without sudo), then make test again" >&2
  exit 1
fi
echo "make test: installing chromium (the view tests open it): ${sudo:+$sudo }$install" >&2
$sudo apt-get update -q
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q chromium
